"""Cross-validation: two interleaved halves of the stills, their projection difference against
what the projection uncertainty predicts.

mrcal's idea (docs "Cross-validation", ``mrcal-show-projection-diff``): calibrate the same lens
from two independent sets of stills; if the lens model and the data are adequate, the two
models differ only by noise, i.e. by about what their projection uncertainties predict. A
difference far above that says the model cannot represent the lens (or some stills carry an
error the corner noise does not explain): the stated uncertainty would then be too small.

Here (at infinity, as ``mrcal-show-projection-diff``'s default):

1. Fit half A (stills 0, 2, 4, ... in name order) and half B (1, 3, 5, ...), each from the full
   fit, with the full fit's kept corners (:func:`cvsflow.calibration.bundle.refine_fit`).
2. On a pixel grid q0 (inside the area both halves covered), unproject with A,
   ``v_A = unproject_A(q0)``, rotate into B's camera frame and project with B:
   ``d(q0) = project_B(R v_A) - q0``. The rotation R (the camera frames of two calibrations
   differ by a rotation the intrinsics imply) is fitted by weighted least squares, weights
   ``1 / (sigma_A^2 + sigma_B^2)`` (mrcal weights by the uncertainties too).
3. Predicted covariance of the stacked differences: ``C = J_A Var(b_A) J_A^T + J_B Var(b_B)
   J_B^T`` with the mean-frames Jacobians of :mod:`cvsflow.calibration.projection_uncertainty` (A and B are
   independent), carried through the rotation fit: ``C_r = M C M^T``, ``M`` the fit's
   residual-maker. The statistic ``T = d_r^T C_r^+ d_r`` is chi-square with ``rank(C_r)`` dof
   when the model is right; ``sqrt(T / dof)`` is reported as ``ratio`` (~1), with the
   pointwise ratio ``|d_r| / worst-direction sigma`` over the grid.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cvsflow.calibration.bundle import MIN_CORNERS_PER_STILL, BundleFit, refine_fit
from cvsflow.calibration.lens import project, project_camera_points, unproject
from cvsflow.calibration.projection_uncertainty import (
    coverage_mask,
    projection_jacobian,
    worst_direction_std,
)

#: ``ratio`` above this is a warning: the halves differ by more than their uncertainty allows.
RATIO_WARN = 2.0
#: Floor added to the predicted covariance, as a share of its pointwise RMS sigma: directions in
#: which the halves' difference is predicted far below a pixel fraction (1e-5 px and less:
#: smooth higher-order shapes) are judged against this floor instead. Without it rounding, the
#: linearisation and the corners' small correlated errors decide the statistic there: on
#: OpenCV's stills the rational model's halves gave a ratio of 6 while every pointwise ratio
#: was below 0.8; a relative eigenvalue cutoff instead is unstable when one direction dominates.
FLOOR_FRAC = 0.1


def split_halves(n: int) -> tuple[list[int], list[int]]:
    """Interleaved halves of n stills.

    Parameters
    ----------
    n : int

    Returns
    -------
    (list of int, list of int)
        (0, 2, 4, ...), (1, 3, 5, ...).
    """
    return list(range(0, n, 2)), list(range(1, n, 2))


def fit_subset(views, fit: BundleFit, idx: list[int]) -> tuple[list, BundleFit]:
    """The stills ``idx`` fitted alone, started from the full fit, with its kept corners.

    Parameters
    ----------
    views : list of StillView
    fit : BundleFit
        The fit of every still.
    idx : list of int
        The stills to fit.

    Returns
    -------
    views : list of StillView
        Those stills.
    fit : BundleFit
        Their fit.
    """
    sub = [views[i] for i in idx]
    f = refine_fit(sub, fit.size_wh, fit.model, fit.theta, fit.rvecs[idx], fit.tvecs[idx],
                   [fit.inlier[i] for i in idx])
    return sub, f


def _skew_rows(v):
    """(G, 3, 3): d (w x v) / d w = -[v]x per row."""
    x, y, z = v[:, 0], v[:, 1], v[:, 2]
    o = np.zeros_like(x)
    return -np.stack([np.stack([o, -z, y], -1), np.stack([z, o, -x], -1),
                      np.stack([-y, x, o], -1)], 1)


def _rot(w):
    th = np.linalg.norm(w)
    if th < 1e-15:
        return np.eye(3)
    k = w / th
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def projection_difference(fit_A: BundleFit, fit_B: BundleFit, q0: np.ndarray,
                          weights: np.ndarray | None = None, iterations: int = 10):
    """``project_B(R v_A(q0)) - q0`` with the best rotation R, at infinity.

    Parameters
    ----------
    fit_A, fit_B : BundleFit
    q0 : ndarray, shape (G, 2)
        Pixels, px.
    weights : ndarray, shape (G,), optional
        Weights of the rotation fit (default 1).
    iterations : int
        Gauss-Newton steps of the rotation.

    Returns
    -------
    d_px : ndarray, shape (G, 2)
        The difference after the rotation fit, px.
    R_BA : ndarray, shape (3, 3)
        The fitted rotation from A's camera frame to B's.
    X : ndarray, shape (2G, 3)
        d d / d omega at the solution (the rotation fit's design matrix).
    """
    v = unproject(q0, fit_A.theta, fit_A.model)
    w = np.ones(len(q0)) if weights is None else np.asarray(weights, float)
    R = np.eye(3)
    for _ in range(iterations):
        p = v @ R.T
        q, J_p, _ = project_camera_points(p, fit_B.theta, fit_B.model)
        d = q - q0
        X = np.einsum("gij,gjk->gik", J_p, _skew_rows(p)).reshape(-1, 3)
        W = np.repeat(w, 2)
        step = np.linalg.lstsq(X * np.sqrt(W)[:, None], -(d.ravel() * np.sqrt(W)), rcond=None)[0]
        R = _rot(step) @ R
        if np.linalg.norm(step) < 1e-12:
            break
    p = v @ R.T
    q, J_p, _ = project_camera_points(p, fit_B.theta, fit_B.model)
    X = np.einsum("gij,gjk->gik", J_p, _skew_rows(p)).reshape(-1, 3)
    return q - q0, R, X


def cross_validate(views, fit: BundleFit, grid_n: tuple = (20, 15),
                   ratio_warn: float = RATIO_WARN) -> dict:
    """Cross-validation of a fit on two interleaved halves of its stills.

    Parameters
    ----------
    views : list of StillView
    fit : BundleFit
        The fit on all stills (its kept corners are used by both halves).
    grid_n : (int, int)
        Grid points across and down the image.
    ratio_warn : float
        ``ratio`` above this adds a warning.

    Returns
    -------
    dict
        ``halves`` (names of A and B), ``theta_A``, ``theta_B``, ``n_points`` (grid points in
        the area both covered), ``ratio`` (sqrt of chi-square over dof; ~1 for an adequate
        model), ``chi2``, ``dof``, ``diff_rms_px`` and ``diff_max_px`` (the rotation-fitted
        difference over those points), ``predicted_rms_px`` (sqrt of the mean trace / 2 of its
        predicted covariance), ``pointwise_ratio_median`` / ``_max``, ``map`` (``u_px``,
        ``v_px``, ``diff_px`` (nv, nu) over the whole grid, ``ratio`` (nv, nu), ``covered``),
        ``warning`` (str or None).
    """
    n = len(views)
    ia, ib = split_halves(n)
    va, fa = fit_subset(views, fit, ia)
    vb, fb = fit_subset(views, fit, ib)
    w, h = fit.size_wh
    us = np.linspace(0, w - 1, grid_n[0])
    vs = np.linspace(0, h - 1, grid_n[1])
    uu, vv = np.meshgrid(us, vs)
    q_all = np.c_[uu.ravel(), vv.ravel()]
    cov_a = coverage_mask([v.uv_px[m] for v, m in zip(va, fa.inlier, strict=True)], fit.size_wh)
    cov_b = coverage_mask([v.uv_px[m] for v, m in zip(vb, fb.inlier, strict=True)], fit.size_wh)
    both = (cov_a & cov_b)[vv.astype(int).ravel(), uu.astype(int).ravel()]

    # Pointwise predicted covariances at every grid point (for the weights and the map).
    Ja_all, _ = projection_jacobian(fa, q_all, np.inf)
    Jb_all, _ = projection_jacobian(fb, q_all, np.inf)
    Ca = np.einsum("gip,pq,gjq->gij", Ja_all, fa.cov, Ja_all)
    Cb = np.einsum("gip,pq,gjq->gij", Jb_all, fb.cov, Jb_all)
    s2 = worst_direction_std(Ca) ** 2 + worst_direction_std(Cb) ** 2
    wts = np.where(both, 1.0 / s2, 0.0)
    d_all, R, X_all = projection_difference(fa, fb, q_all, wts)

    sel = np.flatnonzero(both)
    G = len(sel)
    rows = np.c_[2 * sel, 2 * sel + 1].ravel()
    d = d_all[sel].ravel()
    X = X_all[rows]
    W = np.repeat(wts[sel], 2)
    # Residual-maker of the weighted rotation fit: d_r = M d0, M = I - X (X'WX)^-1 X'W.
    M = np.eye(2 * G) - X @ np.linalg.solve(X.T @ (X * W[:, None]), (X * W[:, None]).T)
    Ja = Ja_all[sel].reshape(2 * G, -1)
    Jb = Jb_all[sel].reshape(2 * G, -1)
    C = Ja @ fa.cov @ Ja.T + Jb @ fb.cov @ Jb.T
    Cr = M @ C @ M.T
    Cr = 0.5 * (Cr + Cr.T)
    Cr_pts = Cr.reshape(G, 2, G, 2)[np.arange(G), :, np.arange(G), :]
    floor2 = (FLOOR_FRAC ** 2) * float(np.mean(np.trace(Cr_pts, axis1=1, axis2=2)) / 2)
    evals, evecs = np.linalg.eigh(Cr)
    evals = np.maximum(evals, 0.0)
    proj = evecs.T @ d  # d is already the fitted residual (M d = d up to rounding)
    chi2 = float(np.sum(proj**2 / (evals + floor2)))
    dof = float(np.sum(evals / (evals + floor2)))
    ratio = float(np.sqrt(chi2 / dof))
    pt_ratio = np.linalg.norm(d_all[sel], axis=1) / worst_direction_std(Cr_pts)
    ratio_map = np.full(len(q_all), np.nan)
    ratio_map[sel] = pt_ratio
    warning = None
    if ratio > ratio_warn:
        warning = (f"the two halves' projections differ by {ratio:.1f} times what their "
                   f"uncertainty predicts (chi-square {chi2:.0f} on {dof:.1f} dof; RMS difference "
                   f"{np.sqrt(np.mean(d**2) * 2):.3f} px): the lens model or the data are not "
                   f"good enough, so the stated uncertainty is too small")
    return {
        "halves": ([v.name for v in va], [v.name for v in vb]),
        "theta_A": fa.theta.tolist(), "theta_B": fb.theta.tolist(),
        "n_points": G, "ratio": ratio, "chi2": chi2, "dof": dof,
        "diff_rms_px": float(np.sqrt(np.mean(np.sum(d_all[sel] ** 2, axis=1)))),
        "diff_max_px": float(np.max(np.linalg.norm(d_all[sel], axis=1))),
        "predicted_rms_px": float(np.sqrt(np.mean(np.trace(Cr_pts, axis1=1, axis2=2)))),
        "pointwise_ratio_median": float(np.median(pt_ratio)),
        "pointwise_ratio_max": float(np.max(pt_ratio)),
        "map": {"u_px": us, "v_px": vs,
                "diff_px": np.linalg.norm(d_all, axis=1).reshape(vv.shape),
                "ratio": ratio_map.reshape(vv.shape), "covered": both.reshape(vv.shape)},
        "warning": warning,
    }


#: A still is named when leaving it out moves the projection (RMS over the covered area) by
#: more than this many times the full fit's stated projection uncertainty there: the answer
#: then hangs on that one still beyond what the uncertainty admits. A still of leverage h (its
#: share of the information) moves it by about sqrt(h / (1 - h)) sigma when its corners are
#: right, under 1 up to h = 0.5; a ratio to the median still's is no test (a clean still at
#: the edge of the set's geometry reached 3.7 x on eight renders).
INFLUENCE_SIGMA_NAMED = 1.0


def _leave_one_out_thetas(views, fit: BundleFit, active: list[int]) -> np.ndarray:
    """Intrinsics of the fit with each active still left out: one Gauss-Newton step from the
    full fit (its first-order influence), shape (len(active), n_theta)."""
    n_theta = fit.model.n_params
    on = np.diag(fit.JtJ) > 0
    out = []
    for i in active:
        m = fit.inlier[i]
        _, J_pose, J_theta = project(views[i].p_B[m], fit.rvecs[i], fit.tvecs[i], fit.theta,
                                     fit.model)
        J_t = J_theta.reshape(-1, n_theta)
        r = fit.residual_px[i][m].ravel()
        keep = on.copy()
        keep[n_theta + 6 * i: n_theta + 6 * i + 6] = False
        A = fit.JtJ.copy()
        A[:n_theta, :n_theta] -= J_t.T @ J_t
        g = np.zeros(len(A))
        g[:n_theta] = J_t.T @ r  # the others' gradient at the full optimum is -J_i^T r_i
        step = np.linalg.solve(A[np.ix_(keep, keep)], g[keep])
        out.append(fit.theta + step[:n_theta])
    return np.array(out)


def leave_one_out(views, fit: BundleFit, grid_n: tuple = (20, 15)) -> dict:
    """Each still left out in turn: the jackknife standard errors and each still's influence.

    Parameters
    ----------
    views : list of StillView
    fit : BundleFit
        The fit of every still (its kept corners are used by every refit).
    grid_n : (int, int)
        Grid points across and down the image for the projection shift.

    Returns
    -------
    dict
        ``std`` (n_theta,): leave-one-still-out jackknife 1-sigma of the intrinsics (sees an
        error shared by a still's corners, which ``fit.cov`` takes as independent);
        ``influence`` (list, one per still): ``name``, ``shift_px`` (RMS over the area the
        stills covered of the projection's shift at infinity when the still is left out,
        the rotation between the two camera frames fitted away, px), ``shift_sigma`` (the
        same over the full fit's projection uncertainty, RMS of the ratio), ``ratio`` (its
        ``shift_px`` over the median still's); None for a still without a fitted pose.

    Notes
    -----
    Each refit is one Gauss-Newton step from the full fit without the still (its first-order
    influence, exact for a linear model; on OpenCV's stills its jackknife std is within a few
    % of full refits' at a hundredth of the time). The shift is the cross-validation's
    projection difference (:func:`projection_difference`) between the two fits.
    """
    w, h = fit.size_wh
    uu, vv = np.meshgrid(np.linspace(0, w - 1, grid_n[0]), np.linspace(0, h - 1, grid_n[1]))
    covered = coverage_mask([v.uv_px[m] for v, m in zip(views, fit.inlier, strict=True)],
                            fit.size_wh)[vv.astype(int).ravel(), uu.astype(int).ravel()]
    q0 = np.c_[uu.ravel(), vv.ravel()][covered]
    J_q, _ = projection_jacobian(fit, q0, np.inf)
    sigma_q = worst_direction_std(np.einsum("gip,pq,gjq->gij", J_q, fit.cov, J_q))
    active = [i for i, m in enumerate(fit.inlier) if m.sum() >= MIN_CORNERS_PER_STILL]
    thetas = _leave_one_out_thetas(views, fit, active)
    shifts = {}
    for i, theta in zip(active, thetas, strict=True):
        d, _, _ = projection_difference(fit, replace(fit, theta=theta), q0, 1.0 / sigma_q**2)
        norm = np.linalg.norm(d, axis=1)
        shifts[i] = (float(np.sqrt(np.mean(norm**2))),
                     float(np.sqrt(np.mean((norm / sigma_q) ** 2))))
    n = len(thetas)
    std = np.sqrt((n - 1) / n * np.sum((thetas - thetas.mean(axis=0)) ** 2, axis=0))
    median = float(np.median([s[0] for s in shifts.values()]))
    influence = []
    for i, v in enumerate(views):
        if i not in shifts:
            influence.append(None)
            continue
        px, sig = shifts[i]
        influence.append({"name": v.name, "shift_px": px, "shift_sigma": sig,
                          "ratio": px / median if median > 0 else float("nan")})
    return {"std": std, "influence": influence}
