r"""The model of a camera's pose stream against its marker body's: residuals, Jacobian, weights.

Camera frame i at camera time t_i; unknowns the clock offset dt (``t_mocap = t_camera + dt``),
``X = T_Cm_C`` and ``Y = T_W_B``::

    T_W_Cm(t_i + dt) X = Y T_B_C,i        so        P_i = Y^-1 A(t_i + dt) X  ~  M_i = T_B_C,i

with ``A(tau)`` the motion-capture stream as a curve (:class:`cvsflow.geometry.PoseCurve`). The
residual of frame i, in the camera frame C::

    r_rot   = log(R_M^T R_P)            (rad)
    r_trans = R_M^T (p_P - p_M)         (m)

Parameters are right perturbations ``R_X exp(a)`` (a in C), ``p_X + b`` (b in Cm),
``R_Y exp(c)`` (c in B), ``p_Y + d`` (d in W), and dt. With ``J_r`` the right Jacobian of SO(3):

- ``dr_rot/da = J_r^-1(r_rot) J_r(a)``, ``dr_rot/dc = -J_r^-1(r_rot) R_P^T J_r(c)``,
  ``dr_rot/d dt = J_r^-1(r_rot) R_X^T omega`` (omega the marker body's rate, in Cm);
- ``dr_trans/db = R_M^T R_Y^T R_A``, ``dr_trans/dc = R_M^T [p_P]x J_r(c)``,
  ``dr_trans/dd = -R_M^T R_Y^T``, ``dr_trans/d dt = R_M^T R_Y^T (R_A (omega x p_X) + v)``.

The six components are whitened with a robust 6 x 6 scatter of the residuals themselves
(:func:`robust_scatter`): a detector's tilt error and its sideways translation error are one
error (correlation 0.87 and -0.96 on ETH's prime_sense_1, 0.98 on its robot arm set), which
per-component weights would count twice.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cvsflow.geometry import (
    PoseCurve,
    R_from_rvec,
    make_T,
    right_jacobian_inv_SO3,
    right_jacobian_SO3,
    rvec_from_R,
    skew,
)
from cvsflow.uncertainty import chi2_quantile

#: Parameter names, in the order of the parameter vector and of the covariance (dt first).
PARAM_NAMES = ("dt_offset_s", "T_Cm_C_rx", "T_Cm_C_ry", "T_Cm_C_rz", "T_Cm_C_x", "T_Cm_C_y",
               "T_Cm_C_z", "T_W_B_rx", "T_W_B_ry", "T_W_B_rz", "T_W_B_x", "T_W_B_y", "T_W_B_z")  # fmt: skip
#: Residual components of a frame, in C (rad, then m).
RESIDUAL_NAMES = ("rot_x", "rot_y", "rot_z", "trans_x", "trans_y", "trans_z")
#: Smallest residual scale per component (rad, m): exact synthetic streams stay well posed.
SCALE_FLOOR = np.full(6, 1e-5)


@dataclass
class StreamProblem:
    """Camera frames in use, the motion-capture curve and the linearisation point.

    Attributes
    ----------
    t_cam : ndarray, shape (N,)
        Camera frame times, camera clock, s (relative to an epoch).
    R_M, p_M : ndarray, shapes (N, 3, 3), (N, 3)
        Measured ``T_B_C``.
    curve : PoseCurve
        ``T_W_Cm`` on the motion-capture clock.
    T_X0, T_Y0 : ndarray, shape (4, 4)
        ``T_Cm_C`` and ``T_W_B`` at the linearisation point.
    dt0 : float
        Offset at the linearisation point, s.
    W : ndarray, shape (6, 6)
        Whitening of a frame's residual, ``r_w = W r``.
    fit_dt : bool
        Whether dt is a parameter (13 of them) or held at ``dt0`` (12).
    """

    t_cam: np.ndarray
    R_M: np.ndarray
    p_M: np.ndarray
    curve: PoseCurve
    T_X0: np.ndarray
    T_Y0: np.ndarray
    dt0: float
    W: np.ndarray = field(default_factory=lambda: np.eye(6))
    fit_dt: bool = True

    @property
    def n_params(self) -> int:
        """13 with dt, 12 without."""
        return 13 if self.fit_dt else 12

    def unpack(self, x):
        """dt, R_X, p_X, R_Y, p_Y and the rotation perturbations a, c at parameter vector x."""
        k = 1 if self.fit_dt else 0
        dt = self.dt0 + (x[0] if self.fit_dt else 0.0)
        a, b, c, d = x[k : k + 3], x[k + 3 : k + 6], x[k + 6 : k + 9], x[k + 9 : k + 12]
        R_X = self.T_X0[:3, :3] @ R_from_rvec(a)
        R_Y = self.T_Y0[:3, :3] @ R_from_rvec(c)
        return dt, R_X, self.T_X0[:3, 3] + b, R_Y, self.T_Y0[:3, 3] + d, a, c

    def raw(self, x, jac=False):
        """Unwhitened residuals (N, 6) [rad, m] and curve status (N,); with ``jac`` the Jacobian (N, 6, P).

        Frames whose time falls outside the curve or in a gap (status != 0) get zero rows.
        """
        dt, R_X, p_X, R_Y, p_Y, a, c = self.unpack(x)
        R_A, p_A, om, v, status = self.curve.at(self.t_cam + dt)
        R_P = R_Y.T @ R_A @ R_X
        p_P = (np.einsum("nij,j->ni", R_A, p_X) + p_A - p_Y) @ R_Y
        r_rot = rvec_from_R(np.swapaxes(self.R_M, 1, 2) @ R_P).reshape(-1, 3)
        r = np.concatenate([r_rot, np.einsum("nji,nj->ni", self.R_M, p_P - self.p_M)], axis=1)
        r[status != 0] = 0.0
        if not jac:
            return r, status
        J = np.zeros((len(r), 6, self.n_params))
        Ji = right_jacobian_inv_SO3(r_rot)
        RMt = np.swapaxes(self.R_M, 1, 2)
        k = 0
        if self.fit_dt:
            J[:, :3, 0] = np.einsum("nij,nj->ni", Ji, om @ R_X)
            dp = (np.einsum("nij,nj->ni", R_A, np.cross(om, p_X)) + v) @ R_Y
            J[:, 3:, 0] = np.einsum("nij,nj->ni", RMt, dp)
            k = 1
        J[:, :3, k : k + 3] = Ji @ right_jacobian_SO3(a)
        J[:, 3:, k + 3 : k + 6] = RMt @ (R_Y.T @ R_A)
        Jc = right_jacobian_SO3(c)
        J[:, :3, k + 6 : k + 9] = -(Ji @ np.swapaxes(R_P, 1, 2)) @ Jc
        J[:, 3:, k + 6 : k + 9] = (RMt @ skew(p_P)) @ Jc
        J[:, 3:, k + 9 : k + 12] = -RMt @ R_Y.T
        J[status != 0] = 0.0
        return r, status, J

    def fun(self, x):
        """Whitened residuals, flat (6 N,), for ``scipy.optimize.least_squares``."""
        return (self.raw(x)[0] @ self.W.T).ravel()

    def jac(self, x):
        """Jacobian of :meth:`fun`, (6 N, P)."""
        J = np.einsum("ij,njp->nip", self.W, self.raw(x, jac=True)[2])
        return J.reshape(-1, J.shape[2])

    def recentre(self, x):
        """Move the linearisation point to x; the zero vector of x's size (the new x)."""
        dt, R_X, p_X, R_Y, p_Y, _, _ = self.unpack(x)
        self.dt0, self.T_X0, self.T_Y0 = dt, make_T(R_X, p_X), make_T(R_Y, p_Y)
        return np.zeros_like(x)

    def keep(self, mask):
        """Keep only the frames ``mask`` selects (frames the offset moved out of the curve)."""
        self.t_cam, self.R_M, self.p_M = self.t_cam[mask], self.R_M[mask], self.p_M[mask]


def robust_scatter(r, floor=SCALE_FLOOR, full=True, n_iter=10):
    """Robust covariance of residual rows (about zero) and its whitening matrix.

    A Huber-type M-estimate of scatter: weights ``min(1, q90 / d_i^2)`` on the rows' squared
    Mahalanobis distances (q90 the chi-square(6) 90 % quantile), rescaled so that the median
    d^2 is chi-square(6)'s median; it starts from the diagonal of 1.4826 MAD.

    Parameters
    ----------
    r : ndarray, shape (N, 6)
        Residuals (rad, m).
    floor : ndarray, shape (6,)
        Smallest standard deviation per component.
    full : bool
        False: the diagonal (per-component MAD) only.
    n_iter : int
        Most re-weighting rounds.

    Returns
    -------
    S : ndarray, shape (6, 6)
        Scatter (covariance of the Gaussian core), rad^2, m^2.
    W : ndarray, shape (6, 6)
        Whitening ``W = L^-1`` with ``S = L L^T``: ``W r`` has unit covariance.
    """
    sd = np.maximum(1.4826 * np.median(np.abs(r), axis=0), floor)
    S = np.diag(sd**2)
    if full:
        k = r.shape[1]
        q90, q50 = chi2_quantile(0.9, k), chi2_quantile(0.5, k)
        for _ in range(n_iter):
            d2 = np.einsum("ni,ij,nj->n", r, np.linalg.inv(S), r)
            w = np.minimum(1.0, q90 / np.maximum(d2, 1e-300))
            S_new = (r * w[:, None]).T @ r / w.sum()
            S_new *= np.median(np.einsum("ni,ij,nj->n", r, np.linalg.inv(S_new), r)) / q50
            done = np.allclose(S_new, S, rtol=1e-4, atol=0)
            S = S_new
            if done:
                break
        sd = np.sqrt(np.diag(S))
        scale = np.maximum(sd, floor) / sd
        S = S * np.outer(scale, scale)
    return S, np.linalg.inv(np.linalg.cholesky(S))
