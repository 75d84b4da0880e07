"""The calibration fit: intrinsics and one board pose per still, with the covariance of both.

The fit minimises ``sum_k |uv_fit_k - uv_obs_k|^2`` over the kept corners of every still
(Levenberg-Marquardt on OpenCV's analytic Jacobians, started from ``cv2.calibrateCamera`` or
``cv2.fisheye.calibrate``): the problem OpenCV solves, so on the same corners it lands on
OpenCV's answer, but here any corner can be left out by name (:mod:`.outliers`) and the full
covariance of every parameter (intrinsics and poses) is kept for the projection uncertainty
(:mod:`.projection_uncertainty`).

Parameter vector ``b`` (P = n_theta + 6 N): the intrinsics ``theta`` (:mod:`.lens`), then for
each still i ``rvec_C_B`` (3, rad) and ``tvec_C_B`` (3, m). ``Var(b) = s^2 (J^T J)^-1`` with
``s^2 = RSS / (2 n - P)``: OpenCV's ``stdDeviationsIntrinsics`` is its intrinsics' block.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from cvsflow.calibration.lens import LensModel, project, theta_from

#: A still keeps its pose only with at least this many kept corners.
MIN_CORNERS_PER_STILL = 6


@dataclass
class StillView:
    """One still's corners.

    Attributes
    ----------
    name : str
        The still's file name.
    ids : ndarray, shape (n,), int
        Board corner index k of each row (``cvsflow.board.board_object_points``).
    p_B : ndarray, shape (n, 3)
        The corners in the board frame B, m.
    uv_px : ndarray, shape (n, 2)
        Their refined image positions, px.
    """

    name: str
    ids: np.ndarray
    p_B: np.ndarray
    uv_px: np.ndarray


@dataclass
class BundleFit:
    """A converged fit.

    Attributes
    ----------
    model : LensModel
    size_wh : (int, int)
        Image width, height, px.
    theta : ndarray, shape (n_theta,)
        Intrinsics (`lens`).
    rvecs, tvecs : ndarray, shape (N, 3)
        ``rvec_C_B`` (rad), ``tvec_C_B`` (m) of each still.
    inlier : list of ndarray of bool, shape (n_i,)
        The corners the fit used.
    residual_px : list of ndarray, shape (n_i, 2)
        ``uv_fit - uv_obs`` of every corner (the left-out ones too), px.
    sigma_px : float
        Corner noise per coordinate, ``sqrt(RSS / (m - P))`` over the used corners (m their
        coordinates, P the parameters).
    cov : ndarray, shape (P, P)
        ``sigma_px^2 (J^T J)^-1``: covariance of b (``theta``, then each still's rvec, tvec).
    JtJ : ndarray, shape (P, P)
        ``J^T J`` at the optimum (used corners).
    n_used : int
        Corners used.
    n_iter : int
        Levenberg-Marquardt iterations of the last run.
    """

    model: LensModel
    size_wh: tuple
    theta: np.ndarray
    rvecs: np.ndarray
    tvecs: np.ndarray
    inlier: list
    residual_px: list
    sigma_px: float
    cov: np.ndarray
    JtJ: np.ndarray
    n_used: int
    n_iter: int
    names: list = field(default_factory=list)

    @property
    def n_params(self) -> int:
        """P = n_theta + 6 N."""
        return self.model.n_params + 6 * len(self.rvecs)

    @property
    def dof(self) -> int:
        """Degrees of freedom of the residual, 2 n_used - P."""
        return 2 * self.n_used - self.n_params

    @property
    def rms_px(self) -> float:
        """OpenCV's RMS: sqrt(sum |r|^2 / n_used) over the used corners, px."""
        sq = sum(float(np.sum(r[m] ** 2)) for r, m in zip(self.residual_px, self.inlier, strict=True))
        return float(np.sqrt(sq / max(self.n_used, 1)))

    @property
    def theta_std(self) -> np.ndarray:
        """1-sigma of each intrinsic from ``cov`` (px, unitless)."""
        return np.sqrt(np.diag(self.cov)[: self.model.n_params])

    def T_C_B(self) -> np.ndarray:
        """Each still's pose as 4x4 transforms, shape (N, 4, 4), ``p_C = T_C_B p_B`` (m)."""
        out = np.tile(np.eye(4), (len(self.rvecs), 1, 1))
        for i, (r, t) in enumerate(zip(self.rvecs, self.tvecs, strict=True)):
            out[i, :3, :3] = cv2.Rodrigues(r.reshape(3, 1))[0]
            out[i, :3, 3] = t
        return out


def initial_fit(views: list[StillView], size_wh: tuple, model: LensModel):
    """OpenCV's own calibration of the views: the start of the fit.

    Parameters
    ----------
    views : list of StillView
    size_wh : (int, int)
        Image width, height, px.
    model : LensModel

    Returns
    -------
    theta : ndarray, shape (n_theta,)
    rvecs, tvecs : ndarray, shape (N, 3)
    """
    obj = [v.p_B.astype(np.float32).reshape(-1, 1, 3) for v in views]
    img = [v.uv_px.astype(np.float32).reshape(-1, 1, 2) for v in views]
    if model.fisheye:
        obj64 = [o.astype(np.float64) for o in obj]
        img64 = [i.astype(np.float64) for i in img]
        crit = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
        _, K, D, rv, tv = cv2.fisheye.calibrate(obj64, img64, tuple(size_wh), None, None,
                                               flags=model.cv_flags, criteria=crit)
    else:
        _, K, D, rv, tv = cv2.calibrateCamera(obj, img, tuple(size_wh), None, None,
                                              flags=model.cv_flags)
    rvecs = np.array([np.ravel(r) for r in rv], dtype=np.float64)
    tvecs = np.array([np.ravel(t) for t in tv], dtype=np.float64)
    return theta_from(K, D, model), rvecs, tvecs


def _residuals_and_jacobian(views, model, theta, rvecs, tvecs, inlier, with_jacobian=True):
    """Stacked residuals (m,) of the used corners and J (m, P); per still (n_i, 2) all corners."""
    n_theta = model.n_params
    P = n_theta + 6 * len(views)
    per_still, rows_r, rows_J = [], [], []
    for i, v in enumerate(views):
        if with_jacobian:
            uv, J_pose, J_theta = project(v.p_B, rvecs[i], tvecs[i], theta, model)
        else:
            uv = project(v.p_B, rvecs[i], tvecs[i], theta, model, jacobians=False)
        r = uv - v.uv_px
        per_still.append(r)
        m = inlier[i]
        if not m.any():
            continue
        rows_r.append(r[m].ravel())
        if with_jacobian:
            J = np.zeros((2 * int(m.sum()), P))
            J[:, :n_theta] = J_theta[m].reshape(-1, n_theta)
            J[:, n_theta + 6 * i: n_theta + 6 * i + 6] = J_pose[m].reshape(-1, 6)
            rows_J.append(J)
    r = np.concatenate(rows_r) if rows_r else np.zeros(0)
    J = np.concatenate(rows_J) if with_jacobian and rows_J else None
    return r, J, per_still


def refine_fit(views, size_wh, model, theta, rvecs, tvecs, inlier, max_iter=100,
               rel_tol=1e-12) -> BundleFit:
    """Levenberg-Marquardt from a start; the converged `BundleFit` with its covariance.

    Parameters
    ----------
    views : list of StillView
    size_wh : (int, int)
        Image width, height, px.
    model : LensModel
    theta : ndarray, shape (n_theta,)
        Start of the intrinsics.
    rvecs, tvecs : ndarray, shape (N, 3)
        Start of the poses (``initial_fit`` or an earlier fit).
    inlier : list of ndarray of bool, shape (n_i,)
        Corners to use. A still with fewer than ``MIN_CORNERS_PER_STILL`` used corners keeps
        its start pose, frozen (its columns are left out).
    max_iter : int
    rel_tol : float
        Stop when the cost falls by less than this share.

    Returns
    -------
    BundleFit
    """
    theta, rvecs, tvecs = theta.copy(), rvecs.copy(), tvecs.copy()
    n_theta = model.n_params
    N = len(views)
    P = n_theta + 6 * N
    active = np.ones(P, bool)
    for i in range(N):
        if inlier[i].sum() < MIN_CORNERS_PER_STILL:
            active[n_theta + 6 * i: n_theta + 6 * i + 6] = False

    def unpack(x):
        return x[:n_theta], x[n_theta:].reshape(N, 6)[:, :3], x[n_theta:].reshape(N, 6)[:, 3:]

    x = np.r_[theta, np.c_[rvecs, tvecs].ravel()]
    r, J, _ = _residuals_and_jacobian(views, model, *unpack(x), inlier)
    cost = float(r @ r)
    lam = 1e-3
    n_iter = 0
    for _ in range(max_iter):
        n_iter += 1
        Ja = J[:, active]
        A = Ja.T @ Ja
        g = Ja.T @ r
        improved = False
        for _ in range(12):
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), -g)
            x_new = x.copy()
            x_new[active] += step
            r_new, J_new, _ = _residuals_and_jacobian(views, model, *unpack(x_new), inlier)
            cost_new = float(r_new @ r_new)
            if np.isfinite(cost_new) and cost_new <= cost:
                improved = True
                break
            lam *= 10.0
        if not improved:
            break
        drop = cost - cost_new
        x, r, J, cost = x_new, r_new, J_new, cost_new
        lam = max(lam / 10.0, 1e-9)
        if drop <= rel_tol * max(cost, 1e-300):
            break
    theta, rvecs, tvecs = (a.copy() for a in unpack(x))
    r, J, per_still = _residuals_and_jacobian(views, model, theta, rvecs, tvecs, inlier)
    n_used = int(sum(int(m.sum()) for m in inlier))
    P_active = int(active.sum())
    dof = 2 * n_used - P_active
    sigma = float(np.sqrt((r @ r) / dof)) if dof > 0 else float("nan")
    JtJ = np.zeros((P, P))
    Ja = J[:, active]
    JtJ[np.ix_(active, active)] = Ja.T @ Ja
    cov = np.zeros((P, P))
    cov[np.ix_(active, active)] = sigma**2 * np.linalg.inv(JtJ[np.ix_(active, active)])
    return BundleFit(model, tuple(size_wh), theta, rvecs, tvecs, [m.copy() for m in inlier],
                     per_still, sigma, cov, JtJ, n_used, n_iter, [v.name for v in views])
