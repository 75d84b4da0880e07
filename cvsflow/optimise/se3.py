"""The ``se3`` method: joint SE(3) calibration by corner reprojection over all frames.

Unknowns (all shared by every frame; there are no per-frame unknowns):

- the intrinsics fx, fy, cx, cy (px) and the distortion terms k1, k2, p1, p2, k3 that the
  caller frees (OpenCV's 5-term model);
- ``T_Cm_C``: the camera optical frame C in the camera-marker body Cm (rotation as a local
  perturbation ``R_Cm_C = R0_Cm_C @ exp([w_C]x)``, w_C in rad about the axes of C; translation
  t_Cm_C in m, in Cm);
- ``T_Bm_B``: the board frame B in the board-marker body Bm (``R_Bm_B = R0_Bm_B @ exp([w_B]x)``,
  w_B in rad about the axes of B; t_Bm_B in m, in Bm);
- ``dt_offset_s``: the time offset, ``t_vicon_s = t_video_s + dt_offset_s`` (docs/contracts.md),
  a refinement of the sync stage's value.

Residuals: for video frame i at time t_i, the board pose predicted by the Vicon,

    T_C_B,i = inv(T_Cm_C) @ inv(T_W_Cm(t_i + dt)) @ T_W_Bm(t_i + dt) @ T_Bm_B      (1)

projects the board's inner corners (corner k at ((k % nx) s, (k // nx) s, 0) in B) through
K and dist (:func:`project_points`); the residual is observed minus projected, in px, under a
robust loss (soft_l1 or Huber, scale ``f_scale_px``). The Vicon poses are interpolated at
t_i + dt (linear in position, SLERP in rotation) so dt is a continuous unknown.

Initialisation is closed form: the time offset from sync, the intrinsics from calibration,
and T_Cm_C, T_Bm_B from the robot-world/hand-eye problem A_i X = Z B_i
(:func:`solve_hand_eye`, Shah 2013) with A_i = T_Cm_Bm,i (Vicon), B_i = T_C_B,i (PnP),
X = T_Bm_B, Z = T_Cm_C.

Refinement: the unknowns are only the ~22 shared parameters (the board's pose per frame comes
from the Vicon, not from extra unknowns), so every residual depends on all of them and the
Jacobian is dense but narrow (2 P N x 22): there is no sparsity for ``jac_sparsity`` to
exploit. The analytic Jacobian (checked against finite differences) feeds either our
Levenberg-Marquardt on the 22 x 22 normal equations with the robust loss by iterative
reweighting (default, ``solver="lm"``: one m x n product per iteration) or
``scipy.optimize.least_squares`` (``solver="scipy"``, TRF; the same optimum: on the 90 s demo
both give fx to 1e-7 px in about 1.5 s).

Uncertainty: the Gauss-Newton covariance of an M-estimator (Huber 1981, sec. 7.6)
``sigma_eff^2 (J^T J)^-1`` with ``sigma_eff^2 = m/(m-n) mean(psi^2) / mean(psi')^2`` (equal to
``sum r^2 / (m - n)`` for a quadratic loss), and a cluster-robust sandwich
``H^-1 (sum_c g_c g_c^T) H^-1`` over contiguous time blocks (residuals of one frame share the
Vicon pose noise and are not independent). The data-only standard errors are the larger of
the two per parameter; correlations (identifiability) come from ``(J^T J)^-1``. The intrinsics
held fixed are not exact: their calibration uncertainty (camera.yaml ``std``) is carried into
the free estimates through the sensitivity of the solution to them, and the reported
``std_errors`` are the total (see :func:`optimise_se3`, Notes).
"""

from __future__ import annotations

import logging
import time

import cv2
import numpy as np
import pandas as pd
from scipy.optimize import least_squares

from cvsflow import transforms as tf
from cvsflow.calibration import board_object_points
from cvsflow.errors import OptimiseError
from cvsflow.geometry.camera import project_points, project_points_jac
from cvsflow.geometry.transforms import skew
from cvsflow.optimise import OptimiseResult

log = logging.getLogger(__name__)

#: Names of the intrinsic parameters, in the order of the parameter vector.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Intrinsics freed by default.
DEFAULT_FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
#: Names of the six pose parameters of each marker transform (m, rad).
POSE_PARAM_SUFFIXES = ("rx_rad", "ry_rad", "rz_rad", "x_m", "y_m", "z_m")
LOSSES = ("linear", "soft_l1", "huber")
#: 1-sigma of each intrinsic held fixed when camera.yaml has no ``std`` (px for fx..cy, then
#: unitless): a 15-still 640 x 480 calibration at 0.1-0.4 px RMS, rounded up (the demo's stills
#: give 0.3, 0.3, 0.6, 0.5 px, 0.003, 0.03, 2e-4, 2e-4, 0.08; OpenCV's 13 sample stills 0.9,
#: 1.0, 1.0, 1.1 px, 0.012, 0.09, 2e-4, 3e-4, 0.2).
DEFAULT_INTRINSIC_STD = {"fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "k1": 0.01, "k2": 0.05,
                         "p1": 5e-4, "p2": 5e-4, "k3": 0.1}  # fmt: skip
#: Fewest frames the solver accepts.
MIN_FRAMES = 10
# Fewest corners of a frame that enter the fit (a planar pose has 6 dof; PnP needs 4).
MIN_FRAME_CORNERS = 6
#: Half-width (s) of the time window around t_i + dt0 that must hold valid Vicon samples.
DT_MARGIN_S = 0.05
#: Share of a take's smoothed camera samples that must lie within the static tolerance
#: (:func:`is_static`): robust to the short bumps a bridged marker dropout leaves.
STATIC_QUANTILE = 0.95
#: Window (s) of the local quadratic smoothing of a moving camera's track
#: (:func:`smooth_track_local`): flat response to ~20 Hz at 300 Hz, neighbouring samples
#: nearly fully correlated (see its Notes).
CAMERA_MOVING_SMOOTH_S = 0.1


# --------------------------------------------------------------------------- projection


board_points_B = board_object_points  # the board's inner corners in B (m)


def K_from_intrinsics(fx, fy, cx, cy):
    """Camera matrix (3, 3) from focal lengths and principal point, px.

    Parameters
    ----------
    fx, fy : float
        Focal lengths along the image x and y axes, px.
    cx, cy : float
        Principal point, px (image origin at the top-left pixel's centre, OpenCV convention).

    Returns
    -------
    K : ndarray, shape (3, 3)
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``, float.
    """
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


# --------------------------------------------------------------------------- Vicon tracks


def body_track(bodies, body):
    """One rigid body of a bodies table as arrays, sorted by time.

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (long): ``t_s, body, valid, x_m, y_m, z_m, qx, qy, qz, qw``.
    body : str
        ``"camera"`` (T_W_Cm) or ``"board"`` (T_W_Bm).

    Returns
    -------
    t_s : ndarray, shape (N,)
        Vicon-clock times, s.
    T_W_X : ndarray, shape (N, 4, 4)
        Body pose in the Vicon world W, metres; identity where invalid.
    valid : ndarray of bool, shape (N,)

    Raises
    ------
    OptimiseError
        Missing columns, no such body, or fewer than two valid samples.
    """
    need = {"t_s", "body", "valid", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"}
    missing = need - set(bodies.columns)
    if missing:
        raise OptimiseError(
            f"se3: bodies table lacks columns {sorted(missing)} (docs/contracts.md bodies.parquet)"
        )
    sub = bodies[bodies["body"] == body].sort_values("t_s", kind="stable")
    if sub.empty:
        raise OptimiseError(
            f"se3: bodies table has no body {body!r} (has {sorted(set(bodies['body']))})"
        )
    t = sub["t_s"].to_numpy(float)
    q = sub[["qx", "qy", "qz", "qw"]].to_numpy(float, copy=True)
    p = sub[["x_m", "y_m", "z_m"]].to_numpy(float, copy=True)
    valid = sub["valid"].to_numpy(bool) & np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1)
    valid &= np.linalg.norm(np.where(np.isfinite(q), q, 0.0), axis=1) > 0.5
    if valid.sum() < 2:
        raise OptimiseError(f"se3: body {body!r} has {int(valid.sum())} valid samples; need >= 2")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise OptimiseError(
            f"se3: body {body!r}: t_s not strictly increasing at row {i + 1} ({t[i]} -> {t[i + 1]})"
        )
    q[~valid] = [0.0, 0.0, 0.0, 1.0]
    p[~valid] = 0.0
    return t, tf.make_T(tf.R_from_quat(q), p), valid


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


class _Track:
    """Linear/SLERP interpolator of one body track, vectorised over query times."""

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
        self.R = T_W_X[:, :3, :3]
        self.p = T_W_X[:, :3, 3]
        # relative rotation of each sample interval, as a rotation vector in the earlier sample
        self.w = tf.rvec_from_R(np.swapaxes(self.R[:-1], 1, 2) @ self.R[1:])

    def _index(self, tq):
        return np.clip(np.searchsorted(self.t, tq, side="right") - 1, 0, len(self.t) - 2)

    def ok(self, tq):
        """True where tq lies inside the take between two valid samples."""
        tq = np.asarray(tq, float)
        i0 = self._index(tq)
        inside = (tq >= self.t[0]) & (tq <= self.t[-1])
        return inside & self.valid[i0] & self.valid[i0 + 1]

    def __call__(self, tq, rates=False):
        """T_W_X at times tq (K,), shape (K, 4, 4): linear position, SLERP rotation.

        With ``rates``, also the velocity v_W (K, 3), m/s, and the body-frame angular
        velocity omega_X (K, 3), rad/s, of the interpolant (dR/dt = R [omega_X]x).
        """
        tq = np.asarray(tq, float)
        i0 = self._index(tq)
        h = self.t[i0 + 1] - self.t[i0]
        frac = (tq - self.t[i0]) / h
        R = self.R[i0] @ tf.R_from_rvec(frac[:, None] * self.w[i0])  # SLERP
        dp = self.p[i0 + 1] - self.p[i0]
        T = tf.make_T(R, self.p[i0] + frac[:, None] * dp)
        if not rates:
            return T
        return T, dp / h[:, None], self.w[i0] / h[:, None]


def interpolate_body(bodies, body, t_query_s):
    """Pose of one body at arbitrary Vicon-clock times (linear position, SLERP rotation).

    Parameters
    ----------
    bodies : DataFrame
        bodies.parquet (see :func:`body_track`).
    body : str
        ``"camera"`` or ``"board"``.
    t_query_s : array_like, shape (K,)
        Vicon-clock times, s.

    Returns
    -------
    T_W_X : ndarray, shape (K, 4, 4)
        Interpolated pose, metres; NaN where ``ok`` is False.
    ok : ndarray of bool, shape (K,)
        Query inside the take, between two valid samples.
    """
    track = _Track(*body_track(bodies, body))
    tq = np.atleast_1d(np.asarray(t_query_s, float))
    T = track(tq)
    ok = track.ok(tq)
    T[~ok] = np.nan
    return T, ok


# --------------------------------------------------------------------------- hand-eye init


def solve_hand_eye(T_Cm_Bm, T_C_B):
    """Closed-form T_Cm_C and T_Bm_B from pose pairs (robot-world/hand-eye, AX = ZB).

    Parameters
    ----------
    T_Cm_Bm : ndarray, shape (N, 4, 4)
        Board-marker body in the camera-marker body, from the Vicon (A_i), metres.
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera optical frame, from PnP (B_i), metres.

    Returns
    -------
    T_Cm_C : ndarray, shape (4, 4)
        Camera optical frame in the camera-marker body (Z), metres.
    T_Bm_B : ndarray, shape (4, 4)
        Board frame in the board-marker body (X), metres.

    Raises
    ------
    OptimiseError
        Fewer than 3 pairs, mismatched shapes, or rotations too alike to separate X from Z.

    Notes
    -----
    T_Cm_Bm,i @ T_Bm_B = T_Cm_C @ T_C_B,i, i.e. A_i X = Z B_i. Rotation: R_A R_X = R_Z R_B is
    linear in (vec R_X, vec R_Z) via Kronecker products,
    [I (x) R_A, -(R_B^T (x) I)] [vec R_X; vec R_Z] = 0 (Shah 2013, "Solving the robot-world/
    hand-eye calibration problem using the Kronecker product", eq. 11); the null vector is
    scaled to det > 0 and each block projected to SO(3). Translation:
    [R_A, -I] [t_X; t_Z] = R_Z t_B - t_A, linear least squares (Shah eq. 14). This is the
    problem ``cv2.calibrateRobotWorldHandEye`` solves with A = cTw ("world2cam"),
    X = wTb ("base2world"), Z = cTg ("gripper2cam"), B = gTb ("base2gripper").
    """
    A = np.asarray(T_Cm_Bm, float)
    B = np.asarray(T_C_B, float)
    if A.shape != B.shape or A.ndim != 3 or A.shape[1:] != (4, 4):
        raise OptimiseError(
            f"se3 hand-eye: T_Cm_Bm {A.shape} and T_C_B {B.shape}; expected equal (N, 4, 4)"
        )
    keep = np.isfinite(A).all(axis=(1, 2)) & np.isfinite(B).all(axis=(1, 2))
    A, B = A[keep], B[keep]
    n = len(A)
    if n < 3:
        raise OptimiseError(f"se3 hand-eye: {n} usable pose pairs; need at least 3")
    RA, RB = A[:, :3, :3], B[:, :3, :3]
    eye3 = np.eye(3)
    # rows of each pair: (I (x) R_A) vec X - (R_B^T (x) I) vec Z = 0  (column-major vec)
    M = np.concatenate(
        [
            np.einsum("ij,nkl->nikjl", eye3, RA).reshape(n, 9, 9),
            -np.einsum("nji,kl->nikjl", RB, eye3).reshape(n, 9, 9),
        ],
        axis=2,
    )
    MtM = np.einsum("nij,nik->jk", M, M)
    evals, evecs = np.linalg.eigh(MtM)
    if evals[1] < 1e-9 * max(evals[-1], 1e-300) * n:
        raise OptimiseError(
            "se3 hand-eye: the board rotations are too alike to separate T_Cm_C from T_Bm_B "
            f"(second smallest eigenvalue {evals[1]:.3g}); the board must turn about two axes"
        )
    v = evecs[:, 0]
    X = v[:9].reshape(3, 3, order="F")
    Z = v[9:].reshape(3, 3, order="F")
    if np.linalg.det(X) < 0:
        X, Z = -X, -Z
    R_X, R_Z = _project_SO3(X), _project_SO3(Z)
    # translations: R_A t_X - t_Z = R_Z t_B - t_A
    lhs = np.concatenate([RA, -np.broadcast_to(eye3, RA.shape)], axis=2).reshape(3 * n, 6)
    rhs = (np.einsum("ij,nj->ni", R_Z, B[:, :3, 3]) - A[:, :3, 3]).reshape(3 * n)
    t_XZ = np.linalg.lstsq(lhs, rhs, rcond=None)[0]
    return tf.make_T(R_Z, t_XZ[3:]), tf.make_T(R_X, t_XZ[:3])


def _project_SO3(M):
    """Nearest rotation matrix (Frobenius) to a 3x3 matrix."""
    U, _, Vt = np.linalg.svd(M)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))])
    return U @ D @ Vt


# --------------------------------------------------------------------------- corners, PnP


def corner_arrays(corners, n_corners, min_corners=MIN_FRAME_CORNERS):
    """Found frames of a corners table as arrays, missing corners as NaN.

    A frame may hold a subset of the corners (a hand or the image border hides the others,
    docs/contracts.md corners.parquet); it is kept with at least ``min_corners`` of them.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet: ``frame, t_s, found, corner, u_px, v_px``.
    n_corners : int
        Inner corners per board (P).
    min_corners : int
        Fewest finite corners a frame needs to be kept.

    Returns
    -------
    frame : ndarray of int, shape (F,)
    t_s : ndarray, shape (F,)
        Video times, s.
    uv_px : ndarray, shape (F, P, 2)
        Observed distorted pixels, corner k in row k; NaN where corner k was not seen.

    Raises
    ------
    OptimiseError
        Missing columns or no frame with ``min_corners`` corners.
    """
    need = {"frame", "t_s", "found", "corner", "u_px", "v_px"}
    missing = need - set(corners.columns)
    if missing:
        raise OptimiseError(
            f"se3: corners table lacks columns {sorted(missing)} (docs/contracts.md corners.parquet)"
        )
    c = corners[corners["found"].astype(bool) & (corners["corner"] >= 0)]
    c = c[c["corner"] < n_corners].drop_duplicates(["frame", "corner"])
    if c.empty:
        raise OptimiseError("se3: corners table has no found frame")
    frames = np.sort(c["frame"].unique())
    t = c.groupby("frame")["t_s"].first().reindex(frames).to_numpy(float)
    uv = np.full((len(frames), n_corners, 2), np.nan)
    fi = np.searchsorted(frames, c["frame"].to_numpy())
    ci = c["corner"].to_numpy(int)
    uv[fi, ci, 0] = c["u_px"].to_numpy(float)
    uv[fi, ci, 1] = c["v_px"].to_numpy(float)
    seen = np.isfinite(uv).all(axis=2)
    uv[~seen] = np.nan
    n_seen = seen.sum(axis=1)
    keep = (n_seen >= min_corners) & np.isfinite(t)
    n_partial = int((keep & (n_seen < n_corners)).sum())
    if n_partial:
        log.info("se3: %d found frames with only part of the %d corners used", n_partial, n_corners)
    n_bad = int((~keep).sum())
    if n_bad:
        log.warning("se3: %d found frames with fewer than %d corners skipped", n_bad, min_corners)
    if not keep.any():
        raise OptimiseError(
            f"se3: no frame has {min_corners} or more corners with finite u_px, v_px"
        )
    return frames[keep], t[keep], uv[keep]


def solve_pnp_frames(uv_px, p_B, K, dist):
    """PnP pose T_C_B of every frame (IPPE then Levenberg-Marquardt refinement).

    Parameters
    ----------
    uv_px : ndarray, shape (F, P, 2)
        Observed distorted pixels; NaN rows are corners not seen (left out).
    p_B : ndarray, shape (P, 3)
        Corner positions in the board frame B, metres (planar, z = 0).
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        [k1, k2, p1, p2, k3].

    Returns
    -------
    T_C_B : ndarray, shape (F, 4, 4)
        Board in camera, metres; NaN where PnP failed or fewer than 4 corners were seen.
    ok : ndarray of bool, shape (F,)
    """
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    obj = np.asarray(p_B, np.float64).reshape(-1, 1, 3)
    T = np.full((len(uv_px), 4, 4), np.nan)
    ok = np.zeros(len(uv_px), bool)
    for i, uv in enumerate(np.asarray(uv_px, np.float64)):
        seen = np.isfinite(uv).all(axis=1)
        if seen.sum() < 4:
            continue
        img = np.ascontiguousarray(uv[seen]).reshape(-1, 1, 2)
        obj_i = obj if seen.all() else np.ascontiguousarray(obj[seen])
        try:
            good, rvec, tvec = cv2.solvePnP(obj_i, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
            if not good:
                continue
            rvec, tvec = cv2.solvePnPRefineLM(obj_i, img, K, dist, rvec, tvec)
        except cv2.error:
            continue
        if np.isfinite(rvec).all() and np.isfinite(tvec).all() and tvec[2, 0] > 0:
            T[i] = tf.T_from_rvec_tvec(rvec.ravel(), tvec.ravel())
            ok[i] = True
    return T, ok


# --------------------------------------------------------------------------- the model


def _right_jacobian(w):
    """Right Jacobian of SO(3) at w (3,): exp(w + d) = exp(w) exp(Jr(w) d) to first order."""
    w = np.asarray(w, float)
    th = np.linalg.norm(w)
    W = skew(w)
    if th < 1e-8:
        return np.eye(3) - 0.5 * W
    # Chirikjian (2011) eq. 10.86
    return np.eye(3) - (1 - np.cos(th)) / th**2 * W + (th - np.sin(th)) / th**3 * (W @ W)


class _Model:
    """Parameter packing, the residuals of eq. (1) and their analytic Jacobian.

    With a rolling shutter (``fit_ld`` or ``ld0`` != 0) each corner has its own Vicon time
    ``t_i + dt + ld * v_ik`` (v_ik its observed image row, px; eq. 1 at that time); else one
    time per frame, ``t_i + dt``, shared by its corners (arrays carry a corner axis of 1).
    """

    def __init__(self, intr0, free, R0_Cm_C, R0_Bm_B, fit_dt, dt0, t_video, uv, p_B, cam, brd,
                 fit_ld=False, ld0=0.0):  # fmt: skip
        self.intr0 = np.asarray(intr0, float)
        self.free = np.array([name in free for name in INTRINSIC_NAMES])
        self.R0_Cm_C, self.R0_Bm_B = R0_Cm_C, R0_Bm_B
        self.fit_dt, self.dt0 = fit_dt, float(dt0)
        self.fit_ld, self.ld0 = bool(fit_ld), float(ld0)
        self.rolling = self.fit_ld or self.ld0 != 0.0
        self.t_video = t_video
        self.uv = uv
        self.seen = np.isfinite(uv).all(axis=-1)  # (F, P): corners observed
        # image row of each corner (its capture time under a rolling shutter); 0 where unseen
        self.row = np.where(self.seen, uv[..., 1], 0.0)
        self._all_seen = bool(self.seen.all())
        self.p_B = p_B
        self.cam, self.brd = cam, brd
        self.names = [n for n, f in zip(INTRINSIC_NAMES, self.free, strict=True) if f]
        self.names += [f"T_Cm_C_{s}" for s in POSE_PARAM_SUFFIXES]
        self.names += [f"T_Bm_B_{s}" for s in POSE_PARAM_SUFFIXES]
        if fit_dt:
            self.names.append("dt_offset_s")
        if self.fit_ld:
            self.names.append("line_delay_s")

    @property
    def n_params(self):
        return len(self.names)

    def pack(self, intr, t_Cm_C, t_Bm_B, dt, ld=0.0):
        x = list(np.asarray(intr, float)[self.free])
        x += [0.0, 0.0, 0.0, *t_Cm_C, 0.0, 0.0, 0.0, *t_Bm_B]
        if self.fit_dt:
            x.append(dt)
        if self.fit_ld:
            x.append(ld)
        return np.array(x, float)

    def _split(self, x):
        nf = int(self.free.sum())
        intr = self.intr0.copy()
        intr[self.free] = x[:nf]
        c = x[nf : nf + 6]
        b = x[nf + 6 : nf + 12]
        dt = x[nf + 12] if self.fit_dt else self.dt0
        ld = x[nf + 12 + int(self.fit_dt)] if self.fit_ld else self.ld0
        return intr, c, b, float(dt), float(ld)

    def unpack(self, x):
        """(intrinsics (9,), T_Cm_C (4, 4), T_Bm_B (4, 4), dt) from a parameter vector."""
        intr, c, b, dt, _ = self._split(x)
        T_Cm_C = tf.make_T(self.R0_Cm_C @ tf.R_from_rvec(c[:3]), c[3:])
        T_Bm_B = tf.make_T(self.R0_Bm_B @ tf.R_from_rvec(b[:3]), b[3:])
        return intr, T_Cm_C, T_Bm_B, dt

    def line_delay(self, x):
        """The line delay (s per image row) at x (the fixed start when not fitted)."""
        return self._split(x)[4]

    def _query_times(self, dt, ld):
        """Vicon times (F, P) per corner under a rolling shutter, else (F, 1) per frame."""
        if self.rolling:
            return self.t_video[:, None] + dt + ld * self.row
        return (self.t_video + dt)[:, None]

    def _tracks(self, tq, rates):
        """Both bodies at times tq (F, Q): poses (F, Q, 4, 4) (and rates (F, Q, 3))."""
        shape = tq.shape
        flat = tq.ravel()
        out = []
        for track in (self.cam, self.brd):
            if rates:
                T, v, om = track(flat, rates=True)
                out.append((T.reshape(shape + (4, 4)), v.reshape(shape + (3,)),
                            om.reshape(shape + (3,))))  # fmt: skip
            else:
                out.append(track(flat).reshape(shape + (4, 4)))
        return out

    def _points(self, T_Cm_Bm, T_Cm_C, T_Bm_B):
        """Corners in Bm (P, 3), Cm and C (F, P, 3) for the board poses T_Cm_Bm (F, Q, 4, 4)."""
        p_Bm = self.p_B @ T_Bm_B[:3, :3].T + T_Bm_B[:3, 3]  # (P, 3)
        p_Cm = np.einsum("fpij,pj->fpi", T_Cm_Bm[..., :3, :3], p_Bm) + T_Cm_Bm[..., :3, 3]
        p_C = (p_Cm - T_Cm_C[:3, 3]) @ T_Cm_C[:3, :3]  # R_Cm_C^T (p_Cm - t_Cm_C), eq. (1)
        return p_Bm, p_Cm, p_C

    def _evaluate(self, x, want_jac):
        intr, T_Cm_C, T_Bm_B, dt = self.unpack(x)
        _, c, b, _, ld = self._split(x)
        tq = self._query_times(dt, ld)
        if not want_jac:
            T_W_Cm, T_W_Bm = self._tracks(tq, rates=False)
            _, _, p_C = self._points(tf.invert_T(T_W_Cm) @ T_W_Bm, T_Cm_C, T_Bm_B)
            K = K_from_intrinsics(*intr[:4])
            return self._observed(self.uv - project_points(p_C, K, intr[4:]))
        (T_W_Cm, v_Cm, om_Cm), (T_W_Bm, v_Bm, om_Bm) = self._tracks(tq, rates=True)
        T_Cm_Bm = tf.invert_T(T_W_Cm) @ T_W_Bm
        p_Bm, p_Cm, p_C = self._points(T_Cm_Bm, T_Cm_C, T_Bm_B)
        R_Cm_C = T_Cm_C[:3, :3]
        K = K_from_intrinsics(*intr[:4])
        uv, J_p, J_i = project_points_jac(p_C, K, intr[4:])
        F, P = p_C.shape[:2]
        R_C_Bm = R_Cm_C.T @ T_Cm_Bm[..., :3, :3]  # (F, Q, 3, 3)
        R_C_B = R_C_Bm @ T_Bm_B[:3, :3]
        d_pC = np.zeros((F, P, 3, 14))
        d_pC[..., 0:3] = skew(p_C) @ _right_jacobian(c[:3])  # w_C
        d_pC[..., 3:6] = -R_Cm_C.T  # t_Cm_C
        d_pC[..., 6:9] = -np.einsum("fpij,pjk->fpik", R_C_B, skew(self.p_B)) @ _right_jacobian(
            b[:3]
        )  # w_B
        d_pC[..., 9:12] = R_C_Bm  # t_Bm_B
        # dt: the Vicon poses move along their interpolants (v, omega in the body frames)
        dp_W = (
            np.einsum("fpij,fpj->fpi", T_W_Bm[..., :3, :3], np.cross(om_Bm, p_Bm[None]))
            + v_Bm
        )
        dp_Cm = np.einsum("fpji,fpj->fpi", T_W_Cm[..., :3, :3], dp_W - v_Cm) - np.cross(
            om_Cm, p_Cm
        )
        d_pC[..., 12] = dp_Cm @ R_Cm_C
        # line delay: corner k is seen row_k later, so it moves row_k times as far as for dt
        d_pC[..., 13] = d_pC[..., 12] * self.row[..., None]
        cols = list(range(12)) + [12] * self.fit_dt + [13] * self.fit_ld
        J = np.concatenate([J_i[..., self.free], J_p @ d_pC[..., cols]], axis=-1)
        return self._observed(self.uv - uv), -self._observed(J)  # residual = observed - projected

    def residuals(self, x):
        return self._evaluate(x, False).ravel()

    def jacobian(self, x):
        """d residuals / d x, analytic, shape (m, n)."""
        _, J = self._evaluate(x, True)
        return J.reshape(-1, J.shape[-1])

    def jacobian_intrinsics(self, x):
        """d residuals / d [fx, fy, cx, cy, k1, k2, p1, p2, k3] at x, free or not, shape (m, 9).

        The columns of the intrinsics held fixed give the sensitivity of the estimate to them
        (see :func:`optimise_se3`, Notes).
        """
        intr, T_Cm_C, T_Bm_B, dt = self.unpack(x)
        T_W_Cm, T_W_Bm = self._tracks(self._query_times(dt, self.line_delay(x)), rates=False)
        _, _, p_C = self._points(tf.invert_T(T_W_Cm) @ T_W_Bm, T_Cm_C, T_Bm_B)
        _, _, J_i = project_points_jac(p_C, K_from_intrinsics(*intr[:4]), intr[4:])
        return -self._observed(J_i).reshape(-1, len(INTRINSIC_NAMES))

    def _observed(self, a):
        """The rows of a per-corner array (F, P, ...) that were observed (no copy if all were)."""
        return a if self._all_seen else a[self.seen]

    def per_corner(self, values):
        """Per-residual ``values`` (m,) back on the (F, 2 P) grid of frames, NaN where unseen."""
        out = np.full(self.seen.shape + (2,), np.nan)
        out[self.seen] = np.asarray(values).reshape(-1, 2)
        return out.reshape(len(out), -1)

    def jacobian_fd(self, x, h=1e-6):
        """Central-difference Jacobian (for tests), shape (m, n)."""
        cols = []
        for j in range(len(x)):
            xp, xm = x.copy(), x.copy()
            xp[j] += h
            xm[j] -= h
            cols.append((self.residuals(xp) - self.residuals(xm)) / (2.0 * h))
        return np.stack(cols, axis=1)


def _loss_weights(r, loss, f_scale):
    """psi(r) and psi'(r) of the robust loss rho(z), z = (r/c)^2 (scipy's definitions)."""
    z = (r / f_scale) ** 2
    if loss == "linear":
        return r, np.ones_like(r)
    if loss == "soft_l1":
        d1 = 1.0 / np.sqrt(1.0 + z)
        d2 = -0.5 * (1.0 + z) ** -1.5
    else:  # huber
        big = z > 1.0
        zs = np.where(big, z, 1.0)
        d1 = np.where(big, zs**-0.5, 1.0)
        d2 = np.where(big, -0.5 * zs**-1.5, 0.0)
    # cost = 0.5 sum c^2 rho(z): gradient row weight psi = rho'(z) r, curvature rho' + 2 z rho''
    return d1 * r, np.maximum(d1 + 2.0 * z * d2, 1e-12)


def _covariances(J, r, loss, f_scale, clusters):
    """Gauss-Newton M-estimator covariance, cluster-robust sandwich, and (J^T J)^-1."""
    m, n = J.shape
    psi, dpsi = _loss_weights(r, loss, f_scale)
    JtJ = _gram(J)
    JtJ_inv = np.linalg.pinv(JtJ)
    # Huber (1981) eq. 7.6.x: sigma_eff^2 = m/(m-n) mean(psi^2) / mean(psi')^2
    sigma2 = (m / max(m - n, 1)) * np.mean(psi**2) / np.mean(dpsi) ** 2
    cov_gn = sigma2 * JtJ_inv
    H = _gram(J, dpsi)
    H_inv = np.linalg.pinv(H)
    g_rows = J * psi[:, None]
    labels, inv = np.unique(clusters, return_inverse=True)
    G = len(labels)
    g_c = np.zeros((G, n))
    np.add.at(g_c, inv, g_rows)
    meat = _gram(g_c) * (G / max(G - 1, 1)) * ((m - 1) / max(m - n, 1))
    cov_cl = H_inv @ meat @ H_inv
    return cov_gn, cov_cl, JtJ_inv, float(sigma2), G


def _fixed_intrinsic_std(camera, names):
    """1-sigma of the fixed intrinsics ``names``: camera["std"], else DEFAULT_INTRINSIC_STD.

    Returns (std (k,), names taken from the default).
    """
    given = camera.get("std") if isinstance(camera, dict) else None
    given = given if isinstance(given, dict) else {}
    sd, defaulted = [], []
    for n in names:
        v = given.get(n)
        try:
            v = float(v)
        except (TypeError, ValueError):
            v = float("nan")
        if not (np.isfinite(v) and v >= 0.0):
            v = DEFAULT_INTRINSIC_STD[n]
            defaulted.append(n)
        sd.append(v)
    return np.array(sd, float), defaulted


def _fixed_sensitivity(J, J_fixed, r, loss, f_scale):
    """S = d x_hat / d theta_fixed = -(J^T W J)^-1 J^T W J_fixed, W = diag psi'(r), (n, k)."""
    dpsi = _loss_weights(r, loss, f_scale)[1]
    H = _gram(J, dpsi)
    B = np.einsum("mi,m,mj->ij", J, dpsi, J_fixed, optimize=False)
    return -np.linalg.pinv(H) @ B


def _corr(cov):
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    return cov / np.outer(d, d)


# --------------------------------------------------------------------------- the solver


def optimise_se3(
    corners,
    bodies,
    camera,
    board,
    dt_offset_s,
    *,
    free=DEFAULT_FREE,
    fit_dt=True,
    loss="soft_l1",
    f_scale_px=1.0,
    max_nfev=100,
    corr_warn=0.95,
    cluster_s=1.0,
    camera_smooth_s=1.0,
    board_smooth_s=0.01,
    camera_static_tol=(0.002, 0.002),
    camera_moving_smooth_s=None,
    solver="lm",
    frames=None,
    init=None,
    fit_line_delay=False,
    line_delay_s=0.0,
):
    """Joint estimate of intrinsics, T_Cm_C, T_Bm_B and the time offset (method ``se3``).

    Parameters
    ----------
    corners : DataFrame
        corners.parquet: ``frame, t_s`` (video clock, s), ``found, corner, u_px, v_px``.
    bodies : DataFrame
        bodies.parquet (native rate, long): ``t_s`` (Vicon clock, s), ``body``
        (``camera``/``board``), ``valid``, ``x_m, y_m, z_m, qx, qy, qz, qw`` (T_W_Cm / T_W_Bm).
    camera : dict
        camera.yaml content: ``K`` (3x3, px) and ``dist`` ([k1, k2, p1, p2, k3]); the start,
        and the values of the intrinsics held fixed; optional ``std`` (name -> 1-sigma, px or
        unitless), the uncertainty of the fixed ones (Notes).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m).
    dt_offset_s : float
        Starting time offset (sync.yaml), t_vicon_s = t_video_s + dt_offset_s.
    free : sequence of str
        Intrinsics to estimate, from ``INTRINSIC_NAMES``; the others stay at ``camera``.
    fit_dt : bool
        Refine the time offset (else held at ``dt_offset_s``).
    loss : {"soft_l1", "huber", "linear"}
        Robust loss on the corner residuals.
    f_scale_px : float
        Scale of the robust loss, px (residuals well below it count quadratically).
    max_nfev : int
        Most residual evaluations of the trust-region solver.
    corr_warn : float
        Warn when two estimates correlate beyond this (absolute value).
    cluster_s : float
        Length (s of video time) of the contiguous blocks of frames treated as independent
        clusters in the cluster-robust covariance.
    camera_smooth_s : float
        Window (s) of the centred moving average applied to the camera body track before the
        static test (:func:`smooth_track`); the track used when ``camera_static_tol`` is None;
        0 uses the raw track.
    camera_static_tol : (float, float) or None
        (m, rad): when the smoothed camera track stays this close to its mean over 95 % of the
        take (:func:`is_static`), the camera is treated as static and its mean pose is used
        for every frame (its marker noise then averages over the take). None: never (the
        track smoothed by ``camera_smooth_s`` is used as it is).
    camera_moving_smooth_s : float or None
        Window (s) of the local quadratic smoothing (:func:`smooth_track_local`) of a camera
        track found moving (hand-held, on a robot); None: ``CAMERA_MOVING_SMOOTH_S``
        (Notes, Moving camera).
    board_smooth_s : float
        Window (s) of the moving average of the board body track (a few Vicon samples: it
        takes the marker noise out of the interpolant's slope, which otherwise puts kinks in
        the cost as a function of dt at every 1/300 s, since 300 Hz is a multiple of 30 fps).
    solver : {"lm", "scipy"}
        ``lm``: Levenberg-Marquardt on the 22 x 22 normal equations with the robust loss by
        iterative reweighting (fast: the work per iteration is one m x n product);
        ``scipy``: ``scipy.optimize.least_squares`` (TRF, exact trust-region solver: an SVD of
        the m x n Jacobian per iteration). Both minimise the same robust cost.
    frames : array_like of int, optional
        Video frames to fit on (e.g. the training blocks); default all usable frames.
    init : dict, optional
        ``T_Cm_C`` and ``T_Bm_B`` (4x4, m) to start from instead of the hand-eye closed form
        (e.g. a board that never turns, or a previous fit).
    fit_line_delay : bool
        Estimate the rolling shutter's line delay (s per image row): corner k of frame i is
        then compared with the Vicon at ``t_i + dt + line_delay_s * v_ik`` (v_ik its observed
        row, px), as Kalibr's rolling-shutter camera model does. False (default): a global
        shutter, every corner at ``t_i + dt`` (unless ``line_delay_s`` is non-zero).
    line_delay_s : float
        The line delay's start (fitted) or its known value (held), s per row; 0 with
        ``fit_line_delay`` False is the global shutter.

    Returns
    -------
    OptimiseResult
        ``iterations``: one row per accepted-or-tried step (``nfev, cost, fx_px, fy_px,
        dt_offset_s``); ``errors``: the per-frame table of :func:`apply_se3` for the fitted
        frames (plus ``rms_px``, ``weight_min``); ``result``: the result.yaml mapping (see
        Notes).

    Raises
    ------
    OptimiseError
        Bad tables, fewer than ``MIN_FRAMES`` usable frames, bad options, or a failed
        hand-eye initialisation.

    Notes
    -----
    ``result`` keys: ``method``; ``K`` (3x3), ``dist`` (5); ``T_Cm_C``, ``T_Bm_B`` (4x4) and their
    ``*_pose6`` [x, y, z, roll, pitch, yaw] (m, rad); ``dt_offset_s``; ``estimates``
    (name -> value) and ``std_errors`` (name -> total 1-sigma) of every free parameter
    (rotation parameters are the local perturbations about the axes of C and B, so their sigma
    is the rotation uncertainty in rad about those axes); ``std_errors_data`` (from the video
    data alone: the larger of ``std_errors_gn`` and ``std_errors_cluster`` per parameter);
    ``std_errors_fixed`` (the part carried in from the fixed intrinsics), with
    ``std_errors^2 = std_errors_data^2 + std_errors_fixed^2``; ``fixed_intrinsics`` (``names``,
    ``values``, ``std`` used, ``std_defaulted``: names whose std came from
    ``DEFAULT_INTRINSIC_STD``, ``sensitivity``: S, rows in the order of ``correlation.names``,
    one column per fixed intrinsic); ``correlation`` (names, matrix: data-only, from
    ``(J^T J)^-1``; the identifiability warnings use it); ``correlation_total`` (of the total
    covariance); ``init`` (the closed-form start); ``n_frames``, ``n_residuals``, ``rms_px``,
    ``sigma_px`` (robust pixel noise, from the M-estimator scale), ``cost``, ``n_iterations``
    (residual evaluations; scipy's TRF takes one per iteration), ``n_jacobians``, ``time_s``,
    ``status``, ``message``, ``warnings`` (list of str); ``line_delay_s`` (s per row) and
    ``fit_line_delay``.

    Moving camera. Eq. (1) holds at each corner's own time for both bodies: T_W_Cm and T_W_Bm
    are interpolated at t_i + dt (+ line_delay_s v_ik) on the same Vicon clock, and the
    derivative w.r.t. dt (and the line delay) carries the velocity of both. A camera held
    still (``camera_static_tol``) is replaced by its mean pose over the take, so its marker
    noise averages out; a camera found moving (hand-held around a fixed board, on a robot) is
    followed sample by sample, smoothed over ``camera_moving_smooth_s`` (by default the
    board's few samples). The 1 s window that tests stillness is never used for a moving
    camera's reference: a centred box keeps sinc(f * 1 s) of a motion of f Hz (64 % at 0.5 Hz),
    which bent the reference by centimetres (a rendered 15 s hand-held session: corner RMS
    10 px, fx 14 px, T_Cm_C 55 mm and dt 50 ms off, held-out errors 104 mm; with the local
    quadratic 0.42 px, 0.2 px, 0.35 mm, 0.13 ms, within 2.4 standard errors, held-out 2.6 mm
    against 1.5 mm for the same video with a fixed camera). The cost of following the
    camera: its body's mrad-level orientation noise (markers 0.17 m apart) enters every
    frame's reference instead of averaging over the take.

    Exposure and rolling shutter. The video time stamp t_i is taken as the mid-exposure time
    of row 0 (the renderer's convention, cvsflow.synth.effects); a constant exposure midpoint
    offset of another camera is the same for every frame, so ``dt_offset_s`` absorbs it. Row
    v is exposed ``v * line_delay_s`` later, which a moving board turns into a shear of the
    image that grows with its speed; the line delay is the slope of that lag in the row and
    is separable from dt only when the board crosses rows while it moves (both are fitted
    from the same motion: their correlation is reported).

    Fixed intrinsics. Parameters the data cannot separate are held at their calibration
    values: the principal point (cx, cy) correlates at ~1.000 with the rotation of the camera
    mounting, since a shift of the image by d px is, to first order, a turn of the camera by
    d / f rad about its y (cx) or x (cy) axis; freeing them only makes the fit trade one for
    the other. Holding them fixed does not make them exact: an error of 0.5 px in cx (about
    one calibration sigma) turns T_Cm_C by 0.7 mrad, several times the data-only standard
    error of a 90 s take, so estimates would sit 6-10 data-only sigma off truth. The estimate
    is a function of the fixed values theta; linearising the M-estimator's normal equations
    ``J^T psi(r) = 0`` about the solution gives its sensitivity

        S = d x_hat / d theta = -(J^T W J)^-1 J^T W J_theta,   W = diag(psi'(r)),

    (J_theta the residuals' derivatives w.r.t. the fixed intrinsics, W the robust curvature
    weights, as in the sandwich covariance), and the calibration's errors, independent of the
    video's, add ``S Sigma_theta S^T`` to the covariance: ``cov_total = cov_data + S
    Sigma_theta S^T`` with ``cov_data`` the data-only standard errors and ``(J^T J)^-1``
    correlations, and ``Sigma_theta`` diagonal from ``camera["std"]`` (OpenCV's
    ``stdDeviationsIntrinsics``, :func:`cvsflow.calibration.calibrate_camera`), or
    ``DEFAULT_INTRINSIC_STD`` for a name it lacks (with a warning). A fit that frees every
    intrinsic has ``std_errors == std_errors_data``.
    """
    t0 = time.perf_counter()
    if loss not in LOSSES:
        raise OptimiseError(f"se3: loss {loss!r}; expected one of {LOSSES}")
    if solver not in ("lm", "scipy"):
        raise OptimiseError(f"se3: solver {solver!r}; expected 'lm' or 'scipy'")
    if not f_scale_px > 0:
        raise OptimiseError(f"se3: f_scale_px {f_scale_px!r}; expected > 0 px")
    bad_free = [f for f in free if f not in INTRINSIC_NAMES]
    if bad_free:
        raise OptimiseError(f"se3: free {bad_free} unknown; expected names from {INTRINSIC_NAMES}")
    try:
        K0 = np.asarray(camera["K"], float).reshape(3, 3)
        dist0 = np.zeros(5)
        d = np.asarray(camera["dist"], float).ravel()[:5]
        dist0[: d.size] = d
    except (KeyError, TypeError, ValueError) as exc:
        raise OptimiseError(
            f"se3: camera {camera!r}: expected K (3x3, px) and dist [k1 k2 p1 p2 k3]"
        ) from exc
    if not (np.isfinite(line_delay_s) and line_delay_s >= 0.0):
        raise OptimiseError(f"se3: line_delay_s {line_delay_s!r}; expected a finite value >= 0 s")
    if not np.isfinite(dt_offset_s):
        raise OptimiseError(f"se3: dt_offset_s {dt_offset_s!r}; expected a finite time in s")
    p_B = board_points_B(board)
    frame, t_video, uv = corner_arrays(corners, len(p_B))
    if frames is not None:
        sel = np.isin(frame, np.asarray(frames))
        frame, t_video, uv = frame[sel], t_video[sel], uv[sel]
    if camera_moving_smooth_s is None:
        camera_moving_smooth_s = CAMERA_MOVING_SMOOTH_S
    cam = _Track(
        *body_track(bodies, "camera"), smooth_s=camera_smooth_s, static_tol=camera_static_tol,
        moving_smooth_s=camera_moving_smooth_s,
    )
    brd = _Track(*body_track(bodies, "board"), smooth_s=board_smooth_s)
    log.info("se3: camera body %s", "static (mean pose used)" if cam.static else "moving")
    usable = np.ones(len(frame), bool)
    for off in (-DT_MARGIN_S, 0.0, DT_MARGIN_S):
        tq = t_video + dt_offset_s + off
        usable &= cam.ok(tq) & brd.ok(tq)
    n_skip = int((~usable).sum())
    if n_skip:
        log.warning(
            "se3: %d of %d frames skipped (no valid Vicon pose within %.2f s of t + dt)",
            n_skip,
            len(frame),
            DT_MARGIN_S,
        )
    frame, t_video, uv = frame[usable], t_video[usable], uv[usable]
    if len(frame) < MIN_FRAMES:
        raise OptimiseError(
            f"se3: {len(frame)} frames with corners and valid Vicon poses at t_video + "
            f"{dt_offset_s:.3f} s; need at least {MIN_FRAMES}"
        )

    # --- closed-form start: PnP at the calibrated intrinsics, then AX = ZB
    if init is not None:
        try:
            T_Cm_C0 = np.asarray(init["T_Cm_C"], float).reshape(4, 4)
            T_Bm_B0 = np.asarray(init["T_Bm_B"], float).reshape(4, 4)
        except (KeyError, TypeError, ValueError) as exc:
            raise OptimiseError(f"se3: init {init!r}: expected T_Cm_C and T_Bm_B (4x4)") from exc
    else:
        T_C_B_pnp, ok = solve_pnp_frames(uv, p_B, K0, dist0)
        tq = t_video + dt_offset_s
        T_Cm_Bm = tf.invert_T(cam(tq)) @ brd(tq)
        T_Cm_C0, T_Bm_B0 = solve_hand_eye(T_Cm_Bm[ok], T_C_B_pnp[ok])
    intr0 = np.array([K0[0, 0], K0[1, 1], K0[0, 2], K0[1, 2], *dist0])
    model = _Model(
        intr0, set(free), T_Cm_C0[:3, :3], T_Bm_B0[:3, :3], fit_dt, dt_offset_s,
        t_video, uv, p_B, cam, brd, fit_ld=fit_line_delay, ld0=line_delay_s,
    )  # fmt: skip
    x0 = model.pack(intr0, T_Cm_C0[:3, 3], T_Bm_B0[:3, 3], dt_offset_s, line_delay_s)
    r0 = model.residuals(x0)
    if not np.isfinite(r0).all():
        raise OptimiseError("se3: non-finite residuals at the start (board behind the camera?)")
    log.info(
        "se3: %d frames, %d parameters; start RMS %.3f px",
        len(frame),
        model.n_params,
        float(np.sqrt(np.mean(r0**2))),
    )

    history = []
    n_jac = [0]

    def fun(x):
        r = model.residuals(x)
        intr, _, _, dt = model.unpack(x)
        rho = _robust_cost(r, loss, f_scale_px)
        history.append(
            {"nfev": len(history), "cost": rho, "fx_px": intr[0], "fy_px": intr[1],
             "dt_offset_s": dt, "rms_px": float(np.sqrt(np.mean(r**2)))}
        )  # fmt: skip
        return r

    def jac(x):
        n_jac[0] += 1
        return model.jacobian(x)

    if solver == "scipy":
        sol = least_squares(
            fun, x0, jac=jac, method="trf", loss=loss, f_scale=f_scale_px, x_scale="jac",
            max_nfev=max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-10,
        )  # fmt: skip
    else:
        sol = _levenberg_marquardt(fun, jac, x0, loss, f_scale_px, max_nfev)
    if not np.isfinite(sol.x).all():
        raise OptimiseError(f"se3: the solver diverged ({sol.message})")
    x = sol.x
    r = model.residuals(x)
    J = model.jacobian(x)
    frame_of_row = np.repeat(np.nonzero(model.seen)[0], 2)
    block = np.floor((t_video - t_video[0]) / max(cluster_s, 1e-9)).astype(int)
    cov_gn, cov_cl, JtJ_inv, sigma2, n_clusters = _covariances(
        J, r, loss, f_scale_px, block[frame_of_row]
    )
    se_gn = np.sqrt(np.diag(cov_gn))
    se_cl = np.sqrt(np.diag(cov_cl))
    se_data = np.maximum(se_gn, se_cl)
    corr = _corr(JtJ_inv)
    cov_data = corr * np.outer(se_data, se_data)
    # uncertainty of the intrinsics held fixed, carried into the free estimates (Notes)
    fixed_names = [n for n in INTRINSIC_NAMES if n not in set(free)]
    warnings_out = []
    names = model.names
    if fixed_names:
        sd_fixed, defaulted = _fixed_intrinsic_std(camera, fixed_names)
        J_fixed = model.jacobian_intrinsics(x)[:, ~model.free]
        S = _fixed_sensitivity(J, J_fixed, r, loss, f_scale_px)
        cov_fixed = (S * sd_fixed**2) @ S.T
        if defaulted:
            msg = (
                f"se3: camera has no std for the fixed {defaulted}; their uncertainty is taken "
                f"as {[DEFAULT_INTRINSIC_STD[n] for n in defaulted]} (DEFAULT_INTRINSIC_STD)"
            )
            warnings_out.append(msg)
            log.warning(msg)
    else:
        sd_fixed, defaulted = np.zeros(0), []
        S = np.zeros((len(names), 0))
        cov_fixed = np.zeros_like(cov_data)
    se_fixed = np.sqrt(np.clip(np.diag(cov_fixed), 0.0, None))
    cov_total = cov_data + cov_fixed
    se = np.sqrt(np.diag(cov_total))
    corr_total = _corr(cov_total)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if abs(corr[i, j]) > corr_warn:
                msg = (
                    f"se3: {names[i]} and {names[j]} correlate at {corr[i, j]:+.3f} "
                    f"(|corr| > {corr_warn}): the data hardly separate them"
                )
                warnings_out.append(msg)
                log.warning(msg)
    if sol.status <= 0:
        msg = f"se3: solver stopped before converging: {sol.message}"
        warnings_out.append(msg)
        log.warning(msg)
    intr, T_Cm_C, T_Bm_B, dt = model.unpack(x)
    ld = model.line_delay(x)
    K = K_from_intrinsics(*intr[:4])
    dist = intr[4:]

    per_frame = apply_se3(
        {"K": K, "dist": dist, "T_Cm_C": T_Cm_C, "T_Bm_B": T_Bm_B, "dt_offset_s": dt,
         "camera_smooth_s": camera_smooth_s, "board_smooth_s": board_smooth_s,
         "camera_static_tol": camera_static_tol, "camera_moving_smooth_s": camera_moving_smooth_s,
         "line_delay_s": ld},
        corners, bodies, board, frames=frame,
    )  # fmt: skip
    rms_frame = np.sqrt(np.nanmean(model.per_corner(r**2), axis=1))
    wmin = _loss_weights(r, loss, f_scale_px)[0] / np.where(r == 0, 1.0, r)
    wmin = np.nanmin(model.per_corner(np.where(r == 0, 1.0, wmin)), axis=1)
    per_frame = per_frame.merge(
        pd.DataFrame({"frame": frame, "rms_px": rms_frame, "weight_min": wmin}), on="frame"
    )
    elapsed = time.perf_counter() - t0
    result = {
        "method": "se3",
        "K": K.tolist(),
        "dist": dist.tolist(),
        "T_Cm_C": T_Cm_C.tolist(),
        "T_Bm_B": T_Bm_B.tolist(),
        "T_Cm_C_pose6": tf.pose6_from_T(T_Cm_C).tolist(),
        "T_Bm_B_pose6": tf.pose6_from_T(T_Bm_B).tolist(),
        "dt_offset_s": dt,
        "line_delay_s": float(ld),
        "fit_line_delay": bool(fit_line_delay),
        "free": [n for n in INTRINSIC_NAMES if n in set(free)],
        "fit_dt": bool(fit_dt),
        "estimates": {n: float(v) for n, v in zip(names, x, strict=True)},
        "std_errors": {n: float(v) for n, v in zip(names, se, strict=True)},
        "std_errors_data": {n: float(v) for n, v in zip(names, se_data, strict=True)},
        "std_errors_fixed": {n: float(v) for n, v in zip(names, se_fixed, strict=True)},
        "fixed_intrinsics": {
            "names": fixed_names,
            "values": [float(intr0[INTRINSIC_NAMES.index(n)]) for n in fixed_names],
            "std": [float(v) for v in sd_fixed],
            "std_defaulted": list(defaulted),
            "sensitivity": np.asarray(S, float).tolist(),
        },
        "std_errors_gn": {n: float(v) for n, v in zip(names, se_gn, strict=True)},
        "std_errors_cluster": {n: float(v) for n, v in zip(names, se_cl, strict=True)},
        "correlation": {"names": list(names), "matrix": np.round(corr, 6).tolist()},
        "correlation_total": {"names": list(names), "matrix": np.round(corr_total, 6).tolist()},
        "init": {
            "K": K0.tolist(),
            "dist": dist0.tolist(),
            "T_Cm_C": T_Cm_C0.tolist(),
            "T_Bm_B": T_Bm_B0.tolist(),
            "dt_offset_s": float(dt_offset_s),
            "rms_px": float(np.sqrt(np.mean(r0**2))),
        },
        "n_frames": len(frame),
        "n_frames_skipped": n_skip,
        "n_residuals": int(r.size),
        "n_clusters": int(n_clusters),
        "cluster_s": float(cluster_s),
        "camera_smooth_s": float(camera_smooth_s),
        "board_smooth_s": float(board_smooth_s),
        "camera_static": bool(cam.static),
        "camera_static_tol": None if camera_static_tol is None else list(camera_static_tol),
        "rms_px": float(np.sqrt(np.mean(r**2))),
        "sigma_px": float(np.sqrt(sigma2)),
        "cost": float(sol.cost),
        "loss": loss,
        "f_scale_px": float(f_scale_px),
        "n_iterations": int(sol.nfev),
        "n_jacobians": int(n_jac[0]),
        "solver": solver,
        "time_s": float(elapsed),
        "status": int(sol.status),
        "message": str(sol.message),
        "warnings": warnings_out,
    }
    if camera_static_tol is not None and not cam.static:  # (a static camera's keys unchanged)
        result["camera_moving_smooth_s"] = float(camera_moving_smooth_s)
    log.info(
        "se3: fx %.2f fy %.2f dt %.4f s, RMS %.3f px, %d evaluations, %.2f s",
        intr[0], intr[1], dt, result["rms_px"], sol.nfev, elapsed,
    )  # fmt: skip
    return OptimiseResult(iterations=pd.DataFrame(history), errors=per_frame, result=result)


def _gram(J, w=None):
    """J^T diag(w) J without BLAS threads (which thrash on a shared machine), (n, n)."""
    if w is None:
        return np.einsum("mi,mj->ij", J, J, optimize=False)
    return np.einsum("mi,m,mj->ij", J, w, J, optimize=False)


class _Solution:
    """The fields of scipy's OptimizeResult that optimise_se3 reads."""

    def __init__(self, x, cost, nfev, njev, status, message):
        self.x, self.cost, self.nfev, self.njev = x, cost, nfev, njev
        self.status, self.message = status, message


def _levenberg_marquardt(fun, jac, x0, loss, f_scale, max_nfev, max_iter=100):
    """Robust Levenberg-Marquardt: IRLS weights, Marquardt-scaled damping, normal equations.

    Minimises 0.5 sum c^2 rho((r/c)^2) (scipy's robust cost). Each iteration: weights
    w = rho'(z) (Triggs et al. 2000, "Bundle adjustment - a modern synthesis", sec. 4.3),
    H = J^T W J, g = J^T W r, step from (H + lambda diag H) dx = -g (Marquardt 1963).
    """
    x = np.asarray(x0, float).copy()
    r = fun(x)
    nfev, njev = 1, 0
    cost = _robust_cost(r, loss, f_scale)
    lam = 1e-3
    status, message = 0, "maximum number of iterations reached"
    for _ in range(max_iter):
        J = jac(x)
        njev += 1
        w = _loss_weights(r, loss, f_scale)[0] / np.where(r == 0, 1.0, r)
        w = np.where(r == 0, 1.0, w)
        H = _gram(J, w)
        g = np.einsum("mi,m->i", J, w * r, optimize=False)
        d = np.maximum(np.diag(H), 1e-300)
        accepted = False
        while nfev < max_nfev:
            try:
                dx = -np.linalg.solve(H + lam * np.diag(d), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            x_new = x + dx
            r_new = fun(x_new)
            nfev += 1
            cost_new = _robust_cost(r_new, loss, f_scale) if np.isfinite(r_new).all() else np.inf
            if cost_new < cost:
                accepted = True
                break
            lam *= 4.0
            if lam > 1e12:
                break
        if not accepted:
            status = 2 if lam > 1e12 else 0
            message = "no cost decrease along the damped step" if status else "max_nfev reached"
            break
        decrease = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        lam = max(lam / 3.0, 1e-9)
        # converged: the step moves no parameter by more than 1e-6 of its own uncertainty scale
        step_sigma = np.abs(dx) * np.sqrt(d) / np.sqrt(max(2.0 * cost / max(len(r), 1), 1e-300))
        if decrease <= 1e-12 * cost or step_sigma.max() < 1e-6:
            status, message = 1, "converged (step below 1e-6 sigma or relative decrease < 1e-12)"
            break
    return _Solution(x, cost, nfev, njev, status, message)


def _robust_cost(r, loss, f_scale):
    """0.5 sum c^2 rho((r/c)^2), scipy's robust cost."""
    z = (r / f_scale) ** 2
    if loss == "linear":
        rho = z
    elif loss == "soft_l1":
        rho = 2.0 * (np.sqrt(1.0 + z) - 1.0)
    else:
        rho = np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    return float(0.5 * f_scale**2 * np.sum(rho))


def apply_se3(params, corners, bodies, board, frames=None):
    """Per-frame CVS pose (PnP at the fitted intrinsics) and Vicon reference pose (eq. 1).

    Parameters
    ----------
    params : dict
        ``K`` (3x3, px), ``dist`` (5), ``T_Cm_C``, ``T_Bm_B`` (4x4, m), ``dt_offset_s`` (s),
        optional ``camera_smooth_s``, ``board_smooth_s`` (s, default 0),
        ``camera_static_tol`` ((m, rad), default None), ``camera_moving_smooth_s`` (s,
        default ``CAMERA_MOVING_SMOOTH_S``) and ``line_delay_s`` (s per row, default 0); e.g.
        ``optimise_se3(...).result``.
    corners : DataFrame
        corners.parquet (``frame, t_s, found, corner, u_px, v_px``).
    bodies : DataFrame
        bodies.parquet (see :func:`body_track`).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    frames : array_like of int, optional
        Frames to evaluate (e.g. a held-out block); default all complete found frames.

    Returns
    -------
    frames : DataFrame
        One row per frame with corners (``corner_arrays``), a PnP solution and valid Vicon poses at
        t + dt (+ line_delay_s times the mean image row of the frame's corners: the PnP pose of
        a rolling-shutter image is, to first order, the board's pose when that row was read):
        ``frame, t_s, t_vicon_s``; CVS pose T_C_B ``cvs_x_m, cvs_y_m, cvs_z_m,
        cvs_qx, cvs_qy, cvs_qz, cvs_qw, cvs_rvec_0..2, cvs_roll_rad, cvs_pitch_rad,
        cvs_yaw_rad``; reference T_C_B from the Vicon with ``ref_`` prefix, same columns
        (no rvec); ``reproj_rms_px`` (PnP reprojection RMS at the fitted intrinsics).
    """
    p_B = board_points_B(board)
    frame, t_video, uv = corner_arrays(corners, len(p_B))
    if frames is not None:
        sel = np.isin(frame, np.asarray(frames))
        frame, t_video, uv = frame[sel], t_video[sel], uv[sel]
    K = np.asarray(params["K"], float)
    dist = np.asarray(params["dist"], float)
    T_Cm_C = np.asarray(params["T_Cm_C"], float)
    T_Bm_B = np.asarray(params["T_Bm_B"], float)
    dt = float(params["dt_offset_s"])
    board_smooth_s = float(params.get("board_smooth_s", 0.0))
    moving_smooth_s = params.get("camera_moving_smooth_s")
    cam = _Track(
        *body_track(bodies, "camera"),
        smooth_s=float(params.get("camera_smooth_s", 0.0)),
        static_tol=params.get("camera_static_tol"),
        moving_smooth_s=CAMERA_MOVING_SMOOTH_S if moving_smooth_s is None else float(moving_smooth_s),
    )
    brd = _Track(*body_track(bodies, "board"), smooth_s=board_smooth_s)
    tq = t_video + dt
    ld = float(params.get("line_delay_s", 0.0) or 0.0)
    if ld != 0.0:
        tq = tq + ld * np.nanmean(uv[..., 1], axis=1)
    ok_vicon = cam.ok(tq) & brd.ok(tq)
    T_ref = tf.invert_T(cam(tq) @ T_Cm_C) @ brd(tq) @ T_Bm_B  # eq. (1)
    T_cvs, ok_pnp = solve_pnp_frames(uv, p_B, K, dist)
    keep = ok_vicon & ok_pnp
    T_ref, T_cvs = T_ref[keep], T_cvs[keep]
    p_C = np.einsum("fij,pj->fpi", T_cvs[:, :3, :3], p_B) + T_cvs[:, None, :3, 3]
    err2 = np.sum((project_points(p_C, K, dist) - uv[keep]) ** 2, axis=-1)  # NaN where unseen
    rms = np.sqrt(np.nanmean(err2, axis=1))
    out = {"frame": frame[keep], "t_s": t_video[keep], "t_vicon_s": tq[keep]}
    for prefix, T in (("cvs_", T_cvs), ("ref_", T_ref)):
        q = tf.quat_from_R(T[:, :3, :3])
        rpy = tf.euler_from_R(T[:, :3, :3]).reshape(-1, 3)
        for j, ax in enumerate("xyz"):
            out[f"{prefix}{ax}_m"] = T[:, j, 3]
        for j, ax in enumerate(("qx", "qy", "qz", "qw")):
            out[f"{prefix}{ax}"] = q[:, j]
        if prefix == "cvs_":
            rv = tf.rvec_from_R(T[:, :3, :3]).reshape(-1, 3)
            for j in range(3):
                out[f"cvs_rvec_{j}"] = rv[:, j]
        for j, ax in enumerate(("roll", "pitch", "yaw")):
            out[f"{prefix}{ax}_rad"] = rpy[:, j]
    out["reproj_rms_px"] = rms
    return pd.DataFrame(out)


def poses_from_table(frames, prefix):
    """Stack of T_C_B (F, 4, 4) from the ``{prefix}x_m .. {prefix}qw`` columns of a table.

    Parameters
    ----------
    frames : DataFrame
        Table with ``{prefix}x_m, {prefix}y_m, {prefix}z_m`` (m) and ``{prefix}qx ..
        {prefix}qw`` (scalar-last quaternion) columns, one row per frame.
    prefix : str
        Column prefix, e.g. ``"cvs_"`` or ``"ref_"``.

    Returns
    -------
    T_C_B : ndarray, shape (F, 4, 4)
        One transform per row (the board B in the camera C), metres. A NaN in a row's
        columns gives NaN entries in that row's transform.
    """
    q = frames[[f"{prefix}qx", f"{prefix}qy", f"{prefix}qz", f"{prefix}qw"]].to_numpy(float)
    t = frames[[f"{prefix}x_m", f"{prefix}y_m", f"{prefix}z_m"]].to_numpy(float)
    return tf.make_T(tf.R_from_quat(q).reshape(-1, 3, 3), t)


# --------------------------------------------------------------------------- synthetic data


def simulate_session(
    seed,
    duration_s=20.0,
    fps=30.0,
    vicon_rate_hz=300.0,
    pixel_noise_px=0.3,
    marker_noise_m=0.0003,
    dt_offset_s=2.37,
    camera_motion_m=0.0,
    board=None,
    max_tilt_rad=0.7,
    line_delay_s=0.0,
    speed=1.0,
    focal_px=700.0,
    handheld_camera=False,
):
    """Corner-level synthetic session with known truth (no rendering): for tests and bench.

    Parameters
    ----------
    seed : int
        Seed of every random choice.
    duration_s : float
        Video length, s.
    fps : float
        Video frame rate, Hz.
    vicon_rate_hz : float
        Vicon sample rate, Hz.
    pixel_noise_px : float
        Standard deviation of the corner noise per axis, px.
    marker_noise_m : float
        Standard deviation of each Vicon marker position per axis, m; the body poses are
        rigid fits of four noisy markers.
    dt_offset_s : float
        True offset, t_vicon = t_video + dt_offset_s.
    camera_motion_m : float
        Amplitude of a slow sway of the camera body (0: static camera).
    handheld_camera : bool
        The camera is hand-held around a fixed board: the board stands still in W (where it
        is at t = 0) and the whole relative motion T_C_B(t) is the camera's,
        T_W_Cm(t) = T_W_B inv(T_C_B(t)) inv(T_Cm_C) (with ``camera_motion_m``'s sway on top
        of the board's fixed pose, if any).
    board : dict, optional
        Board geometry; default 6 x 5 squares of 0.09 m (20 inner corners).
    max_tilt_rad : float
        Largest board roll/pitch/yaw about its facing pose, rad.
    line_delay_s : float
        Rolling shutter: image row v is read ``v * line_delay_s`` after row 0 (whose time is
        the frame time); each corner is where the board was when its row was read.
    speed : float
        Factor on the frequencies of the hand motion (2: twice as fast, same path).
    focal_px : float
        Nominal focal length (px) of the 640 x 480 camera (each of fx, fy drawn about it).

    Returns
    -------
    session : dict
        ``corners`` (corners.parquet table), ``bodies`` (bodies.parquet table),
        ``camera`` (K, dist: the truth), ``board``, ``truth`` (``K, dist, T_Cm_C, T_Bm_B,
        dt_offset_s``, ``T_C_B`` (F, 4, 4) true board poses at the video frames,
        ``frame``, ``t_s``, ``uv_true_px`` (F, P, 2), ``t_corner_s`` (F, P) the time each
        corner was seen, ``line_delay_s``, ``T_W_Cm`` (F, 4, 4) the true camera-marker body at
        the video frames).
    """
    rng = np.random.default_rng(seed)
    if board is None:
        board = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
    p_B = board_points_B(board)
    centre_B = p_B.mean(axis=0)
    K = K_from_intrinsics(
        focal_px + rng.normal(0, 5), focal_px + rng.normal(0, 5), 320 + rng.normal(0, 5),
        240 + rng.normal(0, 5),
    )  # fmt: skip
    dist = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02]) * (1 + 0.1 * rng.normal(size=5))
    T_Cm_C = tf.T_from_pose6(
        [0.03, -0.02, 0.05, -np.pi / 2, 0.0, -np.pi / 2] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_Bm_B = tf.T_from_pose6(
        [0.1, 0.07, -0.004, np.pi, 0.0, 0.0] + rng.normal(0, [0.005] * 3 + [0.03] * 3)
    )
    T_W_Cm0 = tf.T_from_pose6([-1.0, 0.5, 1.2, 0.05, -0.1, 0.3])

    # smooth hand motion: sums of sines per channel (board centre in C, tilt angles)
    def sines(n, f_lo, f_hi):
        f = speed * rng.uniform(f_lo, f_hi, (n, 3))
        ph = rng.uniform(0, 2 * np.pi, (n, 3))
        a = rng.uniform(0.5, 1.0, (n, 3))
        a /= a.sum(axis=1, keepdims=True)
        return lambda t: np.sum(
            a[:, None, :] * np.sin(2 * np.pi * f[:, None, :] * np.asarray(t)[None, :, None]
                                   + ph[:, None, :]), axis=0,
        )  # fmt: skip

    s_pos = sines(6, 0.03, 0.4)
    s_rot = sines(6, 0.05, 0.6)

    def T_C_B_at(t):
        t = np.atleast_1d(np.asarray(t, float))
        s = s_pos(t).T  # (t,) per channel
        z = 2.5 + 1.3 * s[2]
        x = z * 0.22 * s[0]
        y = z * 0.16 * s[1]
        rpy = max_tilt_rad * s_rot(t)
        R = tf.R_from_euler(rpy)
        centre_C = np.stack([x, y, z], axis=1)
        t_C_B = centre_C - (R @ centre_B)
        return tf.make_T(R, t_C_B)

    def sway_at(t):
        t = np.atleast_1d(np.asarray(t, float))
        T = np.repeat(T_W_Cm0[None], len(t), axis=0)
        if camera_motion_m > 0:
            sway = camera_motion_m * np.stack(
                [np.sin(0.2 * t), np.sin(0.13 * t + 1), np.sin(0.17 * t + 2)], axis=1
            )
            T[:, :3, 3] += sway
            T[:, :3, :3] = T[:, :3, :3] @ tf.R_from_euler(2.0 * sway)
        return T

    if handheld_camera:  # the board (Bm) still where it is at t = 0; the camera carries the motion
        T_W_Bm_fixed = T_W_Cm0 @ T_Cm_C @ T_C_B_at(0.0)[0] @ tf.invert_T(T_Bm_B)

        def T_W_Cm_at(t):
            T_W_Bm = sway_at(t) @ tf.invert_T(T_W_Cm0) @ T_W_Bm_fixed
            return T_W_Bm @ T_Bm_B @ tf.invert_T(T_C_B_at(t)) @ tf.invert_T(T_Cm_C)
    else:
        T_W_Cm_at = sway_at

    # video frames and corners
    n_frames = int(round(duration_s * fps))
    t_video = np.arange(n_frames) / fps
    T_C_B = T_C_B_at(t_video)
    p_C = np.einsum("fij,pj->fpi", T_C_B[:, :3, :3], p_B) + T_C_B[:, None, :3, 3]
    uv_true = project_points(p_C, K, dist)
    t_corner = np.repeat(t_video[:, None], len(p_B), axis=1)
    for _ in range(4 if line_delay_s > 0 else 0):  # fixed point: the row read when the corner is
        t_corner = t_video[:, None] + np.clip(uv_true[..., 1], 0, None) * line_delay_s
        T_k = T_C_B_at(t_corner.ravel()).reshape(t_corner.shape + (4, 4))
        p_k = np.einsum("fpij,pj->fpi", T_k[..., :3, :3], p_B) + T_k[..., :3, 3]
        uv_true = project_points(p_k, K, dist)
    uv_obs = uv_true + rng.normal(0, pixel_noise_px, uv_true.shape)
    P = len(p_B)
    corners = pd.DataFrame(
        {
            "frame": np.repeat(np.arange(n_frames), P),
            "t_s": np.repeat(t_video, P),
            "found": True,
            "corner": np.tile(np.arange(P), n_frames),
            "u_px": uv_obs[..., 0].ravel(),
            "v_px": uv_obs[..., 1].ravel(),
        }
    )

    # Vicon: t_vicon = t_video + dt, covering the video with margins; rigid fits of noisy markers
    t_vicon = np.arange(0.0, duration_s + dt_offset_s + 1.0, 1.0 / vicon_rate_hz)
    t_vid_of_vicon = t_vicon - dt_offset_s
    T_W_Cm = T_W_Cm_at(t_vid_of_vicon)
    T_W_Bm = T_W_Cm @ T_Cm_C @ T_C_B_at(t_vid_of_vicon) @ tf.invert_T(T_Bm_B)
    layout = {
        "camera": np.array([[0, 0, 0], [0, 0.16, 0], [0, 0, 0.12], [0, 0.11, 0.17]], float),
        "board": np.array([[0, 0, 0], [0.76, 0, 0], [0, 0.52, 0], [0.58, 0.5, 0]], float),
    }
    rows = []
    for body, T_true in (("camera", T_W_Cm), ("board", T_W_Bm)):
        L = layout[body]
        m_W = np.einsum("nij,kj->nki", T_true[:, :3, :3], L) + T_true[:, None, :3, 3]
        m_W = m_W + rng.normal(0, marker_noise_m, m_W.shape)
        T_fit = _fit_rigid_batch(L, m_W)
        q = tf.quat_from_R(T_fit[:, :3, :3])
        rows.append(
            pd.DataFrame(
                {
                    "frame": np.arange(len(t_vicon)),
                    "t_s": t_vicon,
                    "body": body,
                    "valid": True,
                    "x_m": T_fit[:, 0, 3],
                    "y_m": T_fit[:, 1, 3],
                    "z_m": T_fit[:, 2, 3],
                    "qx": q[:, 0],
                    "qy": q[:, 1],
                    "qz": q[:, 2],
                    "qw": q[:, 3],
                }
            )
        )
    bodies = pd.concat(rows, ignore_index=True)
    truth = {
        "K": K,
        "dist": dist,
        "T_Cm_C": T_Cm_C,
        "T_Bm_B": T_Bm_B,
        "dt_offset_s": float(dt_offset_s),
        "frame": np.arange(n_frames),
        "t_s": t_video,
        "T_C_B": T_C_B,
        "uv_true_px": uv_true,
        "t_corner_s": t_corner,
        "line_delay_s": float(line_delay_s),
        "T_W_Cm": T_W_Cm_at(t_video),
    }
    return {
        "corners": corners,
        "bodies": bodies,
        "camera": {"K": K.tolist(), "dist": dist.tolist()},
        "board": board,
        "truth": truth,
    }


def _fit_rigid_batch(P_body, Q_world):
    """Kabsch fits T_W_X (N, 4, 4) of a body layout (K, 3) to world points (N, K, 3)."""
    pc = P_body.mean(axis=0)
    qc = Q_world.mean(axis=1)
    H = np.einsum("ki,nkj->nij", P_body - pc, Q_world - qc[:, None, :])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    D = np.zeros_like(H)
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)
    t = qc - np.einsum("nij,j->ni", R, pc)
    return tf.make_T(R, t)

