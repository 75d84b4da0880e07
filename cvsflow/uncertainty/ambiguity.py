"""The planar PnP's second solution: where a board's pose is two-fold ambiguous.

A planar board seen small or nearly face-on has two poses that fit its corners almost equally
(IPPE's two solutions, Collins & Bartoli 2014: the board tilted one way, or mirrored about the
line of sight); noise can make the PnP pick the wrong one, an error of up to twice the tilt
that no first-order covariance holds. The mixture of the two solutions, weighted by how much
worse the other fits the corners, has the covariance ``w delta delta^T`` about the measured
pose, ``delta`` the measured minus the other solution and ``w = 1 / (1 + exp(d_ssr / (2
sigma_px^2)))`` the chance that the other one is the true pose (``flip_weight``). The flight's
reference (:func:`cvsflow.flight.reference.pnp_flip_term`) and the sessions' error model
(:func:`cvsflow.uncertainty.features.measurement_features`, model (T)) both add it.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial.transform import Rotation


def pnp_alternatives(uv_px, rvec, tvec, p_B, K, dist):
    """The other IPPE solution of each frame's planar PnP, refined, and its cost excess.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, pixels, NaN where unseen.
    rvec, tvec : ndarray, shape (N, 3)
        The measured poses T_C_B (rad, m).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : ndarray
        The intrinsics of the PnP.

    Returns
    -------
    rvec_alt, tvec_alt : ndarray, shape (N, 3)
        Of the two IPPE solutions, each refined by Levenberg-Marquardt, the one farther in
        rotation from the measured pose; NaN where there is none distinct from it (fewer
        than 4 corners, one solution, or both within 1 microradian of the measured pose).
    d_ssr : ndarray, shape (N,)
        Its sum of squared reprojection residuals minus the measured pose's, px^2 (inf where
        there is no alternative).
    """
    obj = np.asarray(p_B, np.float64)
    K = np.asarray(K, np.float64)
    dist = np.asarray(dist, np.float64).ravel()
    rvec = np.array(rvec, np.float64)  # writable copies (scipy's from_rotvec and OpenCV
    tvec = np.array(tvec, np.float64)  # refuse read-only buffers)
    n = len(uv_px)
    r_alt = np.full((n, 3), np.nan)
    t_alt = np.full((n, 3), np.nan)
    d_ssr = np.full(n, np.inf)

    def ssr(o, img, r, t):
        proj, _ = cv2.projectPoints(o, r, t, K, dist)
        return float(np.sum((proj.reshape(-1, 2) - img.reshape(-1, 2)) ** 2))

    for i in range(n):
        seen = np.isfinite(uv_px[i]).all(axis=1)
        if seen.sum() < 4 or not (np.isfinite(rvec[i]).all() and np.isfinite(tvec[i]).all()):
            continue
        o = np.ascontiguousarray(obj[seen]).reshape(-1, 1, 3)
        img = np.ascontiguousarray(uv_px[i, seen], np.float64).reshape(-1, 1, 2)
        count, rvs, tvs, _ = cv2.solvePnPGeneric(o, img, K, dist, flags=cv2.SOLVEPNP_IPPE)
        R_m = Rotation.from_rotvec(rvec[i])
        best = None
        for r0, t0 in zip(rvs[:count], tvs[:count], strict=True):
            r1, t1 = cv2.solvePnPRefineLM(o, img, K, dist, r0.copy(), t0.copy())
            ang = (Rotation.from_rotvec(r1.ravel()) * R_m.inv()).magnitude()
            if best is None or ang > best[0]:
                best = (ang, r1.ravel(), t1.ravel())
        if best is None or best[0] < 1e-6:
            continue
        _, r_alt[i], t_alt[i] = best
        d_ssr[i] = ssr(o, img, r_alt[i], t_alt[i]) - ssr(o, img, rvec[i].copy(), tvec[i].copy())
    return r_alt, t_alt, d_ssr


def flip_weight(d_ssr, var_px):
    """The chance that the other solution is the true pose: ``1 / (1 + exp(d_ssr / (2
    var_px)))`` (0 where there is no alternative, ``d_ssr`` inf).

    Parameters
    ----------
    d_ssr : ndarray, shape (N,)
        Cost excess of the other solution, px^2 (:func:`pnp_alternatives`).
    var_px : ndarray or float
        Corner noise variance per image axis, px^2.

    Returns
    -------
    w : ndarray, shape (N,)
    """
    d_ssr = np.asarray(d_ssr, float)
    w = 1.0 / (1.0 + np.exp(np.clip(d_ssr / (2.0 * var_px), -50.0, 50.0)))
    return np.where(np.isfinite(d_ssr), w, 0.0)
