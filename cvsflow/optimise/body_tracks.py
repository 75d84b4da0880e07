"""Mocap body tracks for the ``se3`` method: smoothing, the static test, and the interpolant the
solver evaluates (with its rates, for the time offset).

A track is one body of the bodies table as :func:`cvsflow.mocap.body_poses` reads it
(``invalid="identity"``, at least two valid samples). :class:`BodyTrack` interpolates it with
:func:`cvsflow.geometry.interpolate_T` (linear position, SLERP rotation) and adds the rates
the Jacobian in dt needs.
"""

from __future__ import annotations

import numpy as np

from cvsflow.geometry import PoseInterpolant
from cvsflow.geometry import transforms as tf
from cvsflow.mocap import body_poses

#: Share of a take's smoothed camera samples that must lie within the static tolerance
#: (:func:`is_static`): robust to the short bumps a bridged marker dropout leaves.
STATIC_QUANTILE = 0.95
#: Window (s) of the local quadratic smoothing of a moving camera's track
#: (:func:`smooth_track_local`): flat response to ~20 Hz at 300 Hz, neighbouring samples
#: nearly fully correlated (see its Notes).
CAMERA_MOVING_SMOOTH_S = 0.1


def smooth_track(t_s, T_W_X, valid, window_s):
    """Moving average of a body track over a centred window (for a static or slow body).

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, s (uniform rate).
    T_W_X : ndarray, shape (N, 4, 4)
        Body poses in W, metres.
    valid : ndarray of bool, shape (N,)
    window_s : float
        Window length, s; 0 or less returns the track unchanged.

    Returns
    -------
    T_W_X_smooth : ndarray, shape (N, 4, 4)
        Positions averaged over the valid samples of the window; rotations averaged as
        rotation vectors about the take's chordal mean rotation (exact for rotations within a
        few tens of degrees of it).

    Notes
    -----
    The camera of a session is often static and its markers span only ~0.17 m, so the raw
    Vicon orientation of the camera body carries mrad-level noise that reaches ~1 px at the
    board (lever arm of metres). A long window removes it before the static test
    (:func:`is_static`). The centred window has no lag, but it is a low-pass filter: it
    flattens a moving body's path (a 1 s box keeps sinc(f * 1 s) of a sway of f Hz), so a
    moving body is smoothed over a few samples only (``optimise_se3``,
    ``camera_moving_smooth_s``).
    """
    T_W_X = np.asarray(T_W_X, float)
    if window_s <= 0 or len(t_s) < 3:
        return T_W_X.copy()
    rate = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    n = 2 * int(round(0.5 * window_s * rate)) + 1  # odd: a centred window, no time shift
    w = valid.astype(float)
    R_ref = tf.mean_rotation(T_W_X[valid, :3, :3])
    rv = tf.rvec_from_R(R_ref.T @ T_W_X[:, :3, :3])
    kernel = np.ones(n)

    def box(a):
        return np.convolve(a, kernel, mode="same")

    den = np.maximum(box(w), 1e-12)
    p = np.stack([box(w * T_W_X[:, j, 3]) for j in range(3)], axis=1) / den[:, None]
    r = np.stack([box(w * rv[:, j]) for j in range(3)], axis=1) / den[:, None]
    return tf.make_T(R_ref @ tf.R_from_rvec(r), p)


def smooth_track_local(t_s, T_W_X, valid, window_s, order=2, chunk_s=1.0):
    """Local polynomial (Savitzky-Golay) smoothing of a body track, for a moving body.

    Parameters
    ----------
    t_s : ndarray, shape (N,)
        Sample times, s (uniform rate).
    T_W_X : ndarray, shape (N, 4, 4)
        Body poses in W, metres.
    valid : ndarray of bool, shape (N,)
    window_s : float
        Window length, s; 0 or less returns the track unchanged.
    order : int
        Degree of the polynomial fitted by weighted least squares over each centred window
        (the valid samples only).
    chunk_s : float
        Length (s) of the pieces of the take that share one reference rotation.

    Returns
    -------
    T_W_X_smooth : ndarray, shape (N, 4, 4)
        The fitted polynomial at each sample: positions, and rotations as rotation vectors
        about the chordal mean rotation of each ``chunk_s`` piece of the take and its window
        margins (so a body may turn without bound, e.g. a robot circling the board, as long
        as it turns by less than ~150 degrees within one piece); the input pose where fewer
        than ``order + 2`` valid samples lie in the window.

    Notes
    -----
    A moving camera's markers span ~0.17 m, so its raw orientation carries mrad-level noise
    per sample; at 300 Hz and 30 fps every frame meets the Vicon at the same fraction of a
    sample interval, where linear interpolation between independent noisy samples has a
    variance that depends on that fraction, and the fit's dt moves (by up to half a sample)
    to where it is smallest. A smoother whose neighbouring samples are nearly fully
    correlated removes that pull; a box window long enough for it flattens the path
    (sinc(f w) of a motion of f Hz), whereas a local quadratic keeps every path up to its
    third derivative (its response is flat to ~20 Hz for a 0.1 s window at 300 Hz;
    Savitzky and Golay 1964, Schafer 2011 "What is a Savitzky-Golay filter?").
    """
    T_W_X = np.asarray(T_W_X, float)
    if window_s <= 0 or len(t_s) < 3:
        return T_W_X.copy()
    rate = (len(t_s) - 1) / (t_s[-1] - t_s[0])
    half = int(round(0.5 * window_s * rate))
    if half < 1:
        return T_W_X.copy()
    valid = np.asarray(valid, bool)
    n = len(t_s)
    step = max(int(round(chunk_s * rate)), 2 * half + 1)
    out = T_W_X.copy()
    for a in range(0, n, step):  # each piece with the margins its windows reach
        lo, hi = max(a - half, 0), min(a + step + half, n)
        if valid[lo:hi].any():
            piece = _local_poly(T_W_X[lo:hi], valid[lo:hi], half, order)
            out[a : min(a + step, n)] = piece[a - lo : a - lo + min(step, n - a)]
    return out


def _local_poly(T_W_X, valid, half, order):
    """:func:`smooth_track_local` on one piece, about the piece's mean rotation."""
    w = valid.astype(float)
    R_ref = tf.mean_rotation(T_W_X[valid, :3, :3])
    rv = tf.rvec_from_R(R_ref.T @ T_W_X[:, :3, :3])
    y = np.concatenate([T_W_X[:, :3, 3], rv], axis=1) * w[:, None]  # (N, 6), 0 where invalid
    n, m = len(T_W_X), order + 1
    pad = np.pad(w, half)
    ypad = np.pad(y, ((half, half), (0, 0)))
    S = np.zeros((n, 2 * order + 1))  # sum_k w k^p, p = 0 .. 2 order
    b = np.zeros((n, m, 6))  # sum_k w y k^p, p = 0 .. order
    for k in range(-half, half + 1):
        wk = pad[half + k : half + k + n]
        yk = ypad[half + k : half + k + n]
        powers = float(k) ** np.arange(2 * order + 1)
        S += wk[:, None] * powers
        b += yk[:, None, :] * powers[None, :m, None]
    A = S[:, np.arange(m)[:, None] + np.arange(m)[None, :]]  # (N, m, m) Hankel
    ok = S[:, 0] >= order + 2
    ok[ok] = np.abs(np.linalg.det(A[ok])) > 1e-9 * np.abs(A[ok, -1, -1]) ** m
    fit = np.concatenate([T_W_X[:, :3, 3], rv], axis=1)
    fit[ok] = np.linalg.solve(A[ok], b[ok])[:, 0, :]  # the polynomial at k = 0
    return tf.make_T(R_ref @ tf.R_from_rvec(fit[:, 3:]), fit[:, :3])


def is_static(T_W_X, tol_m, tol_rad, quantile=STATIC_QUANTILE):
    """True when a (smoothed) track stays within tol_m and tol_rad of its mean nearly always.

    Parameters
    ----------
    T_W_X : ndarray, shape (N, 4, 4)
        Valid body poses, metres.
    tol_m, tol_rad : float
        Largest deviation of the position (m) and rotation angle (rad) from the mean.
    quantile : float
        Share of the samples that must lie within the tolerances (1: every one).

    Returns
    -------
    bool
        True when the ``quantile`` of the distances of the positions from their mean is at most
        ``tol_m`` and the same quantile of the rotation angles from the mean rotation is at
        most ``tol_rad``.

    Notes
    -----
    A quantile, not the maximum: a marker dropout can throw the rigid-body orientation of a
    0.17 m camera body by tens of mrad for a few samples, which the 1 s moving average spreads
    into a ~2 mrad bump. On the 20 s demo such a bump at video t = 17-19 s (2.04 mrad against a
    2 mrad tolerance) made the camera count as moving, the reference followed it and the
    held-out errors came in a run there. Its cause, a drawn marker layout, is removed upstream
    (``mocap.refine_layout``, docs/findings.md); the quantile stays for what a layout cannot fix
    (a swapped or ghost marker). A camera that truly moves exceeds the tolerance for far more
    than 5 % of a take.
    """
    p = T_W_X[:, :3, 3]
    R_mean = tf.mean_rotation(T_W_X[:, :3, :3])
    dev_m = np.quantile(np.linalg.norm(p - p.mean(axis=0), axis=1), quantile)
    dev_rad = np.quantile(tf.rotation_angle(R_mean.T @ T_W_X[:, :3, :3]), quantile)
    return bool(dev_m <= tol_m and dev_rad <= tol_rad)


class BodyTrack:
    """One body track as the solver evaluates it: smoothed or held static, then interpolated
    (:class:`cvsflow.geometry.PoseInterpolant`: linear position, SLERP rotation, with rates).

    Parameters
    ----------
    t_s, T_W_X, valid
        One body's samples (:func:`cvsflow.mocap.body_poses` with ``invalid="identity"``,
        ``track=True``; :meth:`from_bodies` reads them).
    smooth_s : float
        Window (s) of the centred moving average (:func:`smooth_track`); 0: none.
    static_tol : (float, float) or None
        (m, rad): a track that stays this close to its mean (:func:`is_static`) is replaced
        by its mean pose; None: never tested.
    moving_smooth_s : float or None
        Window (s) of the local quadratic (:func:`smooth_track_local`) of a track found
        moving (applied to the raw track); None: the moving average is kept.
    """

    def __init__(self, t_s, T_W_X, valid, smooth_s=0.0, static_tol=None, moving_smooth_s=None):
        self.t = np.asarray(t_s, float)
        self.valid = np.asarray(valid, bool)
        T_raw = T_W_X
        T_W_X = smooth_track(self.t, T_raw, self.valid, smooth_s)
        self.static = False
        if static_tol is not None:
            self.static = is_static(T_W_X[self.valid], *static_tol)
            if self.static:  # one pose for the take: the mean of every valid sample
                T_mean = tf.make_T(
                    tf.mean_rotation(T_W_X[self.valid, :3, :3]), T_W_X[self.valid, :3, 3].mean(0)
                )
                T_W_X = np.broadcast_to(T_mean, T_W_X.shape).copy()
            elif moving_smooth_s is not None:
                # a centred box has no lag but flattens every curve of the path (a 1 s box
                # keeps 64 % of a 0.5 Hz sway): a moving camera gets a local quadratic instead
                T_W_X = smooth_track_local(self.t, T_raw, self.valid, moving_smooth_s)
        self._track = PoseInterpolant(self.t, T_W_X, self.valid)

    @classmethod
    def from_bodies(cls, bodies, body, **options):
        """The track of one body of a bodies table (:func:`cvsflow.mocap.body_poses`).

        Parameters
        ----------
        bodies : DataFrame
            bodies.parquet.
        body : str
            ``"camera"`` (T_W_Cm) or ``"board"`` (T_W_Bm).
        **options
            ``smooth_s``, ``static_tol``, ``moving_smooth_s`` as the class takes them.

        Returns
        -------
        BodyTrack
        """
        return cls(*body_poses(bodies, body, invalid="identity", min_valid=2, track=True), **options)

    def ok(self, tq):
        """True where tq lies inside the take between two valid samples."""
        return self._track.ok(tq)

    def __call__(self, tq, rates=False):
        """T_W_X at times tq (K,), shape (K, 4, 4): linear position, SLERP rotation.

        With ``rates``, also the velocity v_W (K, 3), m/s, and the body-frame angular
        velocity omega_X (K, 3), rad/s, of the interpolant (dR/dt = R [omega_X]x).
        """
        return self._track(tq, rates)
