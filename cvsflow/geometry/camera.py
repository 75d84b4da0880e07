"""The camera model: OpenCV's pinhole with 5-term distortion [k1, k2, p1, p2, k3].

``cv2.projectPoints`` (calib3d docs, "Detailed description"): x' = X/Z, y' = Y/Z,
r^2 = x'^2 + y'^2, x'' = x'(1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x'y' + p2 (r^2 + 2x'^2),
y'' = y'(1 + ...) + p1 (r^2 + 2y'^2) + 2 p2 x'y', u = fx x'' + cx, v = fy y'' + cy.
Skew is taken as zero. Points are in the camera optical frame C (x right, y down, z forward).

:func:`project_points` evaluates the radial factor in Horner form, :func:`project_points_jac`
term by term, as ``cvsflow.optimise.se3`` always did (it now imports them; its numbers are
bit-identical); the two agree to ~1e-12 px.
"""

from __future__ import annotations

import numpy as np

#: Order of the intrinsics in :func:`project_points_jac`'s second Jacobian.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def project_points(p_C, K, dist):
    """Project camera-frame points to distorted pixels with OpenCV's 5-term model.

    Parameters
    ----------
    p_C : ndarray, shape (..., 3)
        Points in the camera optical frame C (x right, y down, z forward), metres; z > 0.
    K : ndarray, shape (3, 3)
        Camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], px.
    dist : ndarray, shape (5,)
        [k1, k2, p1, p2, k3] (OpenCV order), dimensionless.

    Returns
    -------
    uv_px : ndarray, shape (..., 2)
        Distorted pixel coordinates (u right, v down), px; equal to ``cv2.projectPoints``.
    """
    p_C = np.asarray(p_C, dtype=float)
    K = np.asarray(K, dtype=float)
    k1, k2, p1, p2, k3 = np.asarray(dist, dtype=float).ravel()[:5]
    x = p_C[..., 0] / p_C[..., 2]
    y = p_C[..., 1] / p_C[..., 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    return np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)


def project_points_jac(p_C, K, dist):
    """Distorted pixels and their derivatives w.r.t. the point and the intrinsics.

    Parameters
    ----------
    p_C : ndarray, shape (..., 3)
        Points in the camera optical frame C, metres; z > 0.
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        [k1, k2, p1, p2, k3].

    Returns
    -------
    uv_px : ndarray, shape (..., 2)
        Distorted pixel coordinates, px.
    d_uv_d_p : ndarray, shape (..., 2, 3)
        d(u, v)/d(X, Y, Z) of the point in C, px per metre.
    d_uv_d_intr : ndarray, shape (..., 2, 9)
        d(u, v)/d[fx, fy, cx, cy, k1, k2, p1, p2, k3] (:data:`INTRINSIC_NAMES`): px per px
        for fx .. cy, px per unit for the distortion terms.

    Notes
    -----
    With p_C = R p_B + t, the derivative w.r.t. t is ``d_uv_d_p`` (``cv2.projectPoints``'
    tvec columns) and w.r.t. a left perturbation exp([w]x) R it is ``d_uv_d_p @ -skew(R p_B)``,
    which equals OpenCV's rvec columns only at rvec = 0 (OpenCV differentiates the Rodrigues
    vector itself). ``d_uv_d_intr`` equals OpenCV's columns 6..14 (f, c, then k1 k2 p1 p2 k3).
    """
    p_C = np.asarray(p_C, float)
    fx, fy = K[0, 0], K[1, 1]
    k1, k2, p1, p2, k3 = np.asarray(dist, float).ravel()[:5]
    iz = 1.0 / p_C[..., 2]
    x = p_C[..., 0] * iz
    y = p_C[..., 1] * iz
    r2 = x * x + y * y
    r4 = r2 * r2
    radial = 1.0 + k1 * r2 + k2 * r4 + k3 * r4 * r2
    drad_dr2 = k1 + 2.0 * k2 * r2 + 3.0 * k3 * r4
    xy = x * y
    xd = x * radial + 2.0 * p1 * xy + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * xy
    uv = np.stack([fx * xd + K[0, 2], fy * yd + K[1, 2]], axis=-1)
    # d(xd, yd)/d(x, y)
    a = radial + 2.0 * x * x * drad_dr2 + 2.0 * p1 * y + 6.0 * p2 * x
    b = 2.0 * x * y * drad_dr2 + 2.0 * p1 * x + 2.0 * p2 * y
    d = radial + 2.0 * y * y * drad_dr2 + 6.0 * p1 * y + 2.0 * p2 * x
    # d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]
    J_p = np.zeros(p_C.shape[:-1] + (2, 3))
    J_p[..., 0, 0] = fx * a * iz
    J_p[..., 0, 1] = fx * b * iz
    J_p[..., 0, 2] = -fx * (a * x + b * y) * iz
    J_p[..., 1, 0] = fy * b * iz
    J_p[..., 1, 1] = fy * d * iz
    J_p[..., 1, 2] = -fy * (b * x + d * y) * iz
    J_i = np.zeros(p_C.shape[:-1] + (2, 9))
    J_i[..., 0, 0] = xd
    J_i[..., 1, 1] = yd
    J_i[..., 0, 2] = 1.0
    J_i[..., 1, 3] = 1.0
    J_i[..., 0, 4], J_i[..., 1, 4] = fx * x * r2, fy * y * r2
    J_i[..., 0, 5], J_i[..., 1, 5] = fx * x * r4, fy * y * r4
    J_i[..., 0, 6], J_i[..., 1, 6] = fx * 2.0 * xy, fy * (r2 + 2.0 * y * y)
    J_i[..., 0, 7], J_i[..., 1, 7] = fx * (r2 + 2.0 * x * x), fy * 2.0 * xy
    J_i[..., 0, 8], J_i[..., 1, 8] = fx * x * r4 * r2, fy * y * r4 * r2
    return uv, J_p, J_i
