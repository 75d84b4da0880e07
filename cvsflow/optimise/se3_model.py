"""The residual model of the ``se3`` method: parameter vector, eq. (1) and its Jacobian.

The parameter vector holds the free intrinsics (in the order of ``INTRINSIC_NAMES``), the
rotation perturbation and translation of T_Cm_C and of T_Bm_B, then the time offset and the
line delay when fitted (:mod:`cvsflow.optimise.se3`, module docstring). The camera model is
:mod:`cvsflow.geometry.camera`'s; the Vicon poses come from two
:class:`~cvsflow.optimise.body_tracks.BodyTrack` interpolants.
"""

from __future__ import annotations

import numpy as np

from cvsflow.geometry import INTRINSIC_NAMES, project_points, project_points_jac, right_jacobian_SO3, skew
from cvsflow.geometry import transforms as tf

#: Names of the six pose parameters of each marker transform (m, rad).
POSE_PARAM_SUFFIXES = ("rx_rad", "ry_rad", "rz_rad", "x_m", "y_m", "z_m")


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


class Se3Model:
    """Parameter packing, the residuals of eq. (1) and their analytic Jacobian.

    With a rolling shutter (``fit_ld`` or ``ld0`` != 0) each corner has its own Vicon time
    ``t_i + dt + ld * v_ik`` (v_ik its observed image row, px; eq. 1 at that time); else one
    time per frame, ``t_i + dt``, shared by its corners (arrays carry a corner axis of 1).

    Parameters
    ----------
    intr0 : array_like, shape (9,)
        Start of the intrinsics, in the order of ``INTRINSIC_NAMES``; the fixed ones keep it.
    free : set of str
        Intrinsics estimated.
    R0_Cm_C, R0_Bm_B : ndarray, shape (3, 3)
        Rotations the perturbations w_C, w_B are taken about.
    fit_dt : bool
        The time offset is a parameter (else held at ``dt0``).
    dt0 : float
        Time offset, s, when not fitted.
    t_video : ndarray, shape (F,)
        Video times of the frames, s.
    uv : ndarray, shape (F, P, 2)
        Observed pixels, NaN where a corner was not seen.
    p_B : ndarray, shape (P, 3)
        Corners in the board frame, m.
    cam, brd : BodyTrack
        The camera-marker and board-marker body tracks (T_W_Cm, T_W_Bm).
    fit_ld : bool
        The line delay is a parameter (else held at ``ld0``).
    ld0 : float
        Line delay, s per row, when not fitted.
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
        d_pC[..., 0:3] = skew(p_C) @ right_jacobian_SO3(c[:3])  # w_C
        d_pC[..., 3:6] = -R_Cm_C.T  # t_Cm_C
        d_pC[..., 6:9] = -np.einsum("fpij,pjk->fpik", R_C_B, skew(self.p_B)) @ right_jacobian_SO3(
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
        (see :func:`cvsflow.optimise.se3.optimise_se3`, Notes).
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
        return jacobian_fd(self.residuals, x, h)


def jacobian_fd(residuals, x, h=1e-6):
    """Central-difference Jacobian of ``residuals`` at ``x`` (for tests against the analytic one).

    Parameters
    ----------
    residuals : callable
        ``residuals(x) -> ndarray (m,)``.
    x : ndarray, shape (n,)
        Parameter vector.
    h : float
        Step, in the parameters' units.

    Returns
    -------
    J : ndarray, shape (m, n)
    """
    cols = []
    for j in range(len(x)):
        xp, xm = x.copy(), x.copy()
        xp[j] += h
        xm[j] -= h
        cols.append((residuals(xp) - residuals(xm)) / (2.0 * h))
    return np.stack(cols, axis=1)
