"""Projection uncertainty of a calibration, as mrcal defines it ("mean-frames", mrcal 2.x).

What moves when the corners' noise moves the fit is not a pixel of the intrinsics alone: the
camera frame itself is only defined through the fitted board poses. mrcal's definition (docs
"Projection uncertainty"; ``mrcal.projection_uncertainty``, mrcal 2.2 ``model_analysis.py``):

1. A query pixel ``q0`` is unprojected with the fitted intrinsics to a camera-frame point
   ``p_C = d * v(q0)`` at range ``d`` (``|v| = 1``), or to the direction ``v`` at infinity.
2. That point is carried into every still's board frame with the *fitted* poses,
   ``p_Bi = T_C_Bi^-1 p_C``, and these board-frame points are held fixed: the boards are the
   only physical things the calibration knows.
3. A perturbed fit ``b + db`` maps them back and averages: ``p_C' = (1/N) sum_i T_C_Bi(b+db)
   p_Bi`` (rotations only at infinity), and projects ``q' = project(p_C', theta + dtheta)``.
4. Linearised: ``J_q = dq/dtheta + dq/dp_C (1/N) sum_i d(T_C_Bi p_Bi)/d(rvec_i, tvec_i)``, and
   ``Var(q) = J_q Var(b) J_q^T`` (2x2), ``Var(b) = sigma^2 (J^T J)^-1`` of the fit
   (:attr:`cvsflow.calibration.bundle.BundleFit.cov`). The number reported is the worst direction's standard
   deviation, ``sqrt(largest eigenvalue of Var(q))`` (mrcal's ``worstdirection-stdev``).

Same as mrcal 2.2 for a single camera (its reference frame is the camera; its "frames" are the
board poses ``T_C_B``). Differences, all stated where they enter:

- ``sigma``: here ``sqrt(RSS / (2 n - P))`` (degrees of freedom counted); mrcal takes
  ``np.std`` of the kept residuals (no dof, mean removed): ~3 % smaller on OpenCV's stills.
- mrcal's state also has the board's warp (2 parameters) and, with its default
  regularisation, uses ``Var(b) = s^2 A^-1 J_o^T J_o A^-1`` (observations' rows only); the fit
  here has neither, so it is its plain ``s^2 (J^T J)^-1``.
- mrcal 3 replaced mean-frames by "cross-reprojection" uncertainty; this is mrcal 2's method,
  the one the peer (Debian's mrcal 2.2) reports.
"""

from __future__ import annotations

import cv2
import numpy as np

from cvsflow.calibration.bundle import (
    MIN_CORNERS_PER_STILL,
    BundleFit,
    StillView,
    initial_fit,
    refine_fit,
)
from cvsflow.calibration.lens import (
    lens_model,
    project_camera_points,
    rotate_jacobian,
    unproject,
)


def _active_stills(fit: BundleFit) -> list[int]:
    """Indices of the stills with a fitted pose (at least MIN_CORNERS_PER_STILL kept corners)."""
    return [i for i, m in enumerate(fit.inlier) if m.sum() >= MIN_CORNERS_PER_STILL]


def projection_jacobian(fit: BundleFit, uv_px: np.ndarray, distance_m: float = np.inf
                        ) -> tuple[np.ndarray, np.ndarray]:
    """``dq / db`` of mrcal's mean-frames projection at pixels, and the pixels reprojected.

    Parameters
    ----------
    fit : BundleFit
    uv_px : ndarray, shape (G, 2)
        Query pixels, px.
    distance_m : float
        Range of the query point along its ray, m (``np.inf``: at infinity, rotations only).

    Returns
    -------
    J_q : ndarray, shape (G, 2, P)
        Derivative of the reprojected pixel by the fit's parameters (``theta``, then each
        still's rvec, tvec).
    q_px : ndarray, shape (G, 2)
        The reprojection of the unprojected pixels (equal to ``uv_px`` where the model inverts).
    """
    model = fit.model
    n_theta = model.n_params
    P = fit.n_params
    uv = np.asarray(uv_px, np.float64).reshape(-1, 2)
    G = len(uv)
    v = unproject(uv, fit.theta, model)
    at_inf = not np.isfinite(distance_m)
    p_C = v if at_inf else float(distance_m) * v
    q, J_p, J_theta = project_camera_points(p_C, fit.theta, model)
    J_q = np.zeros((G, 2, P))
    J_q[:, :, :n_theta] = J_theta
    used = _active_stills(fit)
    N = len(used)
    for i in used:
        R = cv2.Rodrigues(fit.rvecs[i].reshape(3, 1))[0]
        p_B = v @ R if at_inf else (p_C - fit.tvecs[i]) @ R  # R^T p, as rows
        _, dRp_dr = rotate_jacobian(fit.rvecs[i], p_B)  # (G, 3, 3)
        c = n_theta + 6 * i
        J_q[:, :, c:c + 3] = np.einsum("gij,gjk->gik", J_p, dRp_dr) / N
        if not at_inf:
            J_q[:, :, c + 3:c + 6] = J_p / N
    return J_q, q


#: A pixel whose unprojection does not reproject to within this distance is outside the region
#: where the fitted model is invertible (a 5- or 8-term polynomial or a fisheye polynomial
#: folding back beyond the angles the boards covered): its uncertainty is undefined (NaN).
ROUNDTRIP_TOL_PX = 0.01


def projection_covariance(fit: BundleFit, uv_px: np.ndarray, distance_m: float = np.inf,
                          sigma_px: float | None = None) -> np.ndarray:
    """Var(q) of mrcal's mean-frames projection at pixels, px^2.

    Parameters
    ----------
    fit : BundleFit
    uv_px : ndarray, shape (G, 2)
    distance_m : float
        Range, m, or ``np.inf``.
    sigma_px : float, optional
        Corner noise per coordinate to propagate (mrcal's ``observed_pixel_uncertainty``);
        default the fit's own ``sigma_px``.

    Returns
    -------
    cov : ndarray, shape (G, 2, 2)
        NaN where the model does not invert (``ROUNDTRIP_TOL_PX``).
    """
    J_q, q = projection_jacobian(fit, uv_px, distance_m)
    cov_b = fit.cov if sigma_px is None else fit.cov * (float(sigma_px) / fit.sigma_px) ** 2
    cov = np.einsum("gip,pq,gjq->gij", J_q, cov_b, J_q)
    bad = ~(np.linalg.norm(q - np.asarray(uv_px, float).reshape(-1, 2), axis=1) <= ROUNDTRIP_TOL_PX)
    cov[bad] = np.nan
    return cov


def worst_direction_std(cov: np.ndarray) -> np.ndarray:
    """Standard deviation in the worst direction of 2x2 covariances (mrcal's formula).

    Parameters
    ----------
    cov : ndarray, shape (..., 2, 2)
        px^2.

    Returns
    -------
    sigma : ndarray, shape (...)
        sqrt of the larger eigenvalue, px.
    """
    a, b, c = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    return np.sqrt((a + c) / 2 + np.sqrt((a - c) ** 2 / 4 + b * b))


def coverage_mask(corner_sets, size_wh: tuple, scale: int = 4) -> np.ndarray:
    """The image area the stills covered: union of each still's corner hull, (H, W) bool.

    Parameters
    ----------
    corner_sets : sequence of ndarray, shape (n_i, 2)
        Each still's (kept) corners, px.
    size_wh : (int, int)
    scale : int
        The mask is drawn at 1/scale resolution and enlarged (a share or a lookup needs no more).

    Returns
    -------
    covered : ndarray, shape (H, W), bool
    """
    w, h = size_wh
    m = np.zeros((max(h // scale, 1), max(w // scale, 1)), np.uint8)
    for uv in corner_sets:
        uv = np.asarray(uv, np.float32).reshape(-1, 2)
        if len(uv) < 3:
            continue
        hull = cv2.convexHull(uv / scale)
        cv2.fillConvexPoly(m, np.rint(hull).astype(np.int32), 1)
    return cv2.resize(m, (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


def median_board_range_m(fit: BundleFit, views) -> float:
    """Median over the stills of the range from the camera to the board's centre.

    Parameters
    ----------
    fit : BundleFit
    views : list of StillView

    Returns
    -------
    float
        m.
    """
    d = []
    for i in _active_stills(fit):
        c_B = views[i].p_B.mean(axis=0)
        R = cv2.Rodrigues(fit.rvecs[i].reshape(3, 1))[0]
        d.append(np.linalg.norm(R @ c_B + fit.tvecs[i]))
    return float(np.median(d))


def uncertainty_map(fit: BundleFit, views, distance_m: float = np.inf, step_px: int = 16,
                    sigma_px: float | None = None) -> dict:
    """Projection uncertainty over the image on a grid, for plotting (no plotting here).

    Parameters
    ----------
    fit : BundleFit
    views : list of StillView
    distance_m : float
        Range, m, or ``np.inf``.
    step_px : int
        Grid spacing, px (the last row and column are the image border).
    sigma_px : float, optional
        See `projection_covariance`.

    Returns
    -------
    dict
        ``u_px`` (nu,), ``v_px`` (nv,): the grid; ``sigma_px`` (nv, nu): worst-direction 1-sigma
        at each grid pixel, px (NaN where the model does not invert); ``covered`` (nv, nu)
        bool: inside the stills' coverage;
        ``corners_uv_px`` (M, 2): the kept corners of every still (to overlay);
        ``distance_m``.
    """
    w, h = fit.size_wh
    us = np.unique(np.r_[np.arange(0, w, step_px), w - 1]).astype(float)
    vs = np.unique(np.r_[np.arange(0, h, step_px), h - 1]).astype(float)
    uu, vv = np.meshgrid(us, vs)
    pts = np.c_[uu.ravel(), vv.ravel()]
    sig = worst_direction_std(projection_covariance(fit, pts, distance_m, sigma_px))
    kept = [v.uv_px[m] for v, m in zip(views, fit.inlier, strict=True)]
    mask = coverage_mask(kept, fit.size_wh)
    covered = mask[vv.astype(int), uu.astype(int)]
    return {"u_px": us, "v_px": vs, "sigma_px": sig.reshape(vv.shape), "covered": covered,
            "corners_uv_px": np.concatenate(kept), "distance_m": float(distance_m)}


def uncertainty_summary(fit: BundleFit, views, distance_m: float | None = None,
                        step_px: int = 16, sigma_px: float | None = None) -> dict:
    """The projection uncertainty at the image centre, its four corners and the worst over the
    covered area, at the stills' median board range and at infinity.

    Parameters
    ----------
    fit : BundleFit
    views : list of StillView
    distance_m : float, optional
        Range, m; default `median_board_range_m`.
    step_px : int
        Grid of the worst-over-area search, px.
    sigma_px : float, optional
        See `projection_covariance`.

    Returns
    -------
    dict
        ``distance_m``; for each of ``at_distance`` and ``at_infinity``: ``centre`` (px),
        ``corners`` (4 values: top-left, top-right, bottom-left, bottom-right, px),
        ``worst_covered`` (px) with ``worst_covered_at_px`` (u, v), ``worst_image`` (px; over
        the whole image, i.e. also where the distortion is extrapolated; inf when some pixel
        does not invert), ``not_invertible_share`` (share of the grid where the model does not
        invert, NaN sigma), ``not_invertible_covered_share`` (the same inside the covered area).
    """
    if distance_m is None:
        distance_m = median_board_range_m(fit, views)
    w, h = fit.size_wh
    pts = np.array([[(w - 1) / 2, (h - 1) / 2], [0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]],
                   float)
    out = {"distance_m": float(distance_m)}
    for key, d in (("at_distance", distance_m), ("at_infinity", np.inf)):
        s = worst_direction_std(projection_covariance(fit, pts, d, sigma_px))
        m = uncertainty_map(fit, views, d, step_px, sigma_px)
        sig = np.where(np.isnan(m["sigma_px"]), np.inf, m["sigma_px"])
        cov_sig = np.where(m["covered"], sig, -np.inf)
        j = np.unravel_index(np.argmax(cov_sig), cov_sig.shape)
        nan = np.isnan(m["sigma_px"])
        out[key] = {"centre": float(s[0]), "corners": [float(x) for x in s[1:]],
                    "worst_covered": float(cov_sig[j]),
                    "worst_covered_at_px": (float(m["u_px"][j[1]]), float(m["v_px"][j[0]])),
                    "worst_image": float(np.max(sig)),
                    "not_invertible_share": float(nan.mean()),
                    "not_invertible_covered_share": float(nan[m["covered"]].mean())}
    return out


def mean_frames_reprojection(theta, model, T_C_B_fit: np.ndarray, T_C_B_ref: np.ndarray,
                             uv_px: np.ndarray, distance_m: float, theta_ref=None):
    """The quantity whose spread the uncertainty predicts, for a Monte-Carlo check.

    A pixel unprojected with the reference intrinsics (``theta_ref``, default ``theta``) to
    a point p_C at ``distance_m`` (or a direction at infinity), carried into the boards'
    frames with the reference poses ``T_C_B_ref`` (N, 4, 4), mapped back with the fitted poses
    ``T_C_B_fit`` (N, 4, 4), averaged, projected with ``theta``.

    Parameters
    ----------
    theta : ndarray, shape (n_theta,)
        Intrinsics projecting the result.
    model : LensModel
    T_C_B_fit, T_C_B_ref : ndarray, shape (N, 4, 4)
        Fitted and reference board poses.
    uv_px : ndarray, shape (G, 2)
        Query pixels, px.
    distance_m : float
        Range, m, or ``np.inf``.
    theta_ref : ndarray, optional
        Intrinsics unprojecting the pixels (default ``theta``).

    Returns
    -------
    q_px : ndarray, shape (G, 2)
    """
    th_ref = theta if theta_ref is None else theta_ref
    v = unproject(uv_px, th_ref, model)
    at_inf = not np.isfinite(distance_m)
    p_C = v if at_inf else distance_m * v
    acc = np.zeros_like(p_C)
    for Tf, Tr in zip(T_C_B_fit, T_C_B_ref, strict=True):
        if at_inf:
            acc += (v @ Tr[:3, :3]) @ Tf[:3, :3].T
        else:
            p_B = (p_C - Tr[:3, 3]) @ Tr[:3, :3]
            acc += p_B @ Tf[:3, :3].T + Tf[:3, 3]
    acc /= len(T_C_B_fit)
    return project_camera_points(acc, theta, model)[0]


def uncertainty_map_of(camera: dict, calib_corners, distance_m: float = np.inf,
                       step_px: int = 16) -> dict:
    """The projection-uncertainty map of a finished calibration, from its two files.

    The fit is run again on the corners the calibration used (``calib_corners.used``): OpenCV's
    start and the Levenberg-Marquardt of :func:`cvsflow.calibration.bundle.refine_fit` land
    on the calibration's own minimum, whose covariance (with the board poses) camera.yaml does
    not hold.

    Parameters
    ----------
    camera : dict
        camera.yaml content (``model``, ``width``, ``height``).
    calib_corners : DataFrame
        ``image, corner, u_px, v_px, X_m, Y_m, used`` (``used`` optional: all when absent).
    distance_m : float
        Range of the query points, m, or ``np.inf``.
    step_px : int
        Grid spacing, px.

    Returns
    -------
    dict
        :func:`uncertainty_map`'s (``u_px``, ``v_px``, ``sigma_px``, ``covered``,
        ``corners_uv_px``, ``distance_m``).
    """
    model = lens_model(camera.get("model", "opencv5"))
    views, inlier = [], []
    for name, block in calib_corners.groupby("image", sort=False):
        used = block["used"].to_numpy(bool) if "used" in block else np.ones(len(block), bool)
        p_B = np.c_[block[["X_m", "Y_m"]].to_numpy(np.float64), np.zeros(len(block))]
        views.append(StillView(str(name), block["corner"].to_numpy(np.int64), p_B,
                               block[["u_px", "v_px"]].to_numpy(np.float64)))
        inlier.append(used)
    size_wh = (int(camera["width"]), int(camera["height"]))
    posed = [i for i, m in enumerate(inlier) if m.sum() >= MIN_CORNERS_PER_STILL]
    views = [views[i] for i in posed]
    inlier = [inlier[i] for i in posed]
    kept = [StillView(v.name, v.ids[m], v.p_B[m], v.uv_px[m]) for v, m in zip(views, inlier,
                                                                                strict=True)]
    theta, rvecs, tvecs = initial_fit(kept, size_wh, model)
    fit = refine_fit(views, size_wh, model, theta, rvecs, tvecs, inlier)
    return uncertainty_map(fit, views, distance_m, step_px)
