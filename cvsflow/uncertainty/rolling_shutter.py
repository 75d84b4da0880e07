"""A rolling shutter's shear of one frame's corners, and the pose PnP gives them without it.

Under a rolling shutter each corner is seen at its own row's time, so a moving board's corners
sit their image velocity times the line delay times their row after the frame's mean row away
from where the board was at the frame's time (the mean row's). :func:`shear_displacement`
gives that displacement; :func:`unsheared_pnp` the pose and reprojection RMS of the corners
with it taken out, which a flight's reference uses (``cvsflow.flight.reference.
correct_rolling_shutter``) and from which the sessions' error model reads the corner noise
(:func:`cvsflow.uncertainty.features.measurement_features`).
"""

from __future__ import annotations

import cv2
import numpy as np


def shear_displacement(uv_px, vel_px_s, line_delay_s):
    """A rolling shutter's displacement of one frame's corners from its mean row's instant.

    Parameters
    ----------
    uv_px : ndarray, shape (n, 2)
        The frame's seen corners.
    vel_px_s : ndarray, shape (n, 2)
        Their image velocities, px/s (NaN: taken as 0).
    line_delay_s : float
        s per row.

    Returns
    -------
    d_uv : ndarray, shape (n, 2)
        px.
    """
    rows = uv_px[:, 1]
    return np.nan_to_num(vel_px_s) * (line_delay_s * (rows - rows.mean()))[:, None]


def unsheared_pnp(uv_px, vel_px_s, rvec, tvec, p_B, K, dist, line_delay_s):
    """Per frame: the PnP pose of its corners with the shear taken out, and their residual.

    The PnP residual of sheared corners holds the part of the shear a pose cannot take up, so
    read as corner noise it overstates it under fast motion. Each frame's corners are moved
    back by :func:`shear_displacement` and PnP is solved on them (Levenberg-Marquardt from the
    measured pose less the shear's pose error to first order: a fast sweep's shear turns the
    pose by tens of mrad, beyond first order).

    Parameters
    ----------
    uv_px, vel_px_s : ndarray, shape (N, P, 2)
        Observed corners (NaN where unseen) and their image velocities, px/s.
    rvec, tvec : ndarray, shape (N, 3)
        The measured PnP poses T_C_B (rad, m).
    p_B : ndarray, shape (P, 3)
        Board corners in B, m.
    K, dist : ndarray
        Intrinsics.
    line_delay_s : float
        s per row.

    Returns
    -------
    rvec_c, tvec_c : ndarray, shape (N, 3)
        The unsheared poses.
    reproj_rms_px : ndarray, shape (N,)
        RMS over each frame's unsheared corners of the residual length, px (as poses_raw's).
    """
    obj = np.asarray(p_B, np.float64)
    seen = np.isfinite(uv_px).all(axis=-1)
    rms = np.empty(len(uv_px))
    rvec_c = np.array(rvec, dtype=float)
    tvec_c = np.array(tvec, dtype=float)
    for i in range(len(uv_px)):
        o = obj[seen[i]].reshape(-1, 1, 3)
        uv_c = uv_px[i, seen[i]] - shear_displacement(uv_px[i, seen[i]], vel_px_s[i, seen[i]],
                                                      line_delay_s)  # fmt: skip
        _, jac = cv2.projectPoints(o, rvec_c[i], tvec_c[i], K, dist)
        J = jac[:, :6]
        d_rt = np.linalg.pinv(J.T @ J) @ (J.T @ (uv_px[i, seen[i]] - uv_c).reshape(-1))
        _, r, t = cv2.solvePnP(o, uv_c.reshape(-1, 1, 2), K, dist, (rvec_c[i] - d_rt[:3]).copy(),
                               (tvec_c[i] - d_rt[3:]).copy(), True, cv2.SOLVEPNP_ITERATIVE)
        rvec_c[i], tvec_c[i] = r.ravel(), t.ravel()
        proj, _ = cv2.projectPoints(o, rvec_c[i], tvec_c[i], K, dist)
        rms[i] = np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - uv_c) ** 2, axis=1)))
    return rvec_c, tvec_c, rms
