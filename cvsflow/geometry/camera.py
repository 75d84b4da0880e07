"""The camera model: OpenCV's pinhole with 5-term distortion [k1, k2, p1, p2, k3].

``cv2.projectPoints`` (calib3d docs, "Detailed description"): x' = X/Z, y' = Y/Z,
r^2 = x'^2 + y'^2, x'' = x'(1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x'y' + p2 (r^2 + 2x'^2),
y'' = y'(1 + ...) + p1 (r^2 + 2y'^2) + 2 p2 x'y', u = fx x'' + cx, v = fy y'' + cy.
Skew is taken as zero. Points are in the camera optical frame C (x right, y down, z forward).

The one projection of the package, in four forms that share the lens (:func:`_distort`) and
its derivatives (:func:`_distort_derivatives`), evaluated in one order (the radial factor in
Horner form, ``(2 p1 x) y``) into few buffers (``out=``: a fresh array per operation, and its
page faults, cost more than the arithmetic in the seed search's stacks):

- :func:`project_points`: points in C to pixels;
- :func:`project_points_jac`: the same with d/d(point) and d/d(intrinsics);
- :func:`project_poses` and :func:`pose_jacobian`: stacks of board poses T_C_B (one focal
  length per row allowed) and d/d(left rotation increment, translation), the seed search's PnP;
- :func:`distort_normalised`: the lens on normalised rays (the renderer's undistortion grid).
"""

from __future__ import annotations

import numpy as np

#: Order of the intrinsics in :func:`project_points_jac`'s second Jacobian.
INTRINSIC_NAMES = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


def _distort(x, y, dist):
    """Distorted normalised coordinates xd, yd (shape of x) and the intermediates
    (r2, radial, 2 p1 x, 2 p2 x) the derivatives reuse; x and y are left unchanged."""
    mul, add = np.multiply, np.add
    k1, k2, p1, p2, k3 = dist
    b = np.empty_like(x)
    r2 = mul(x, x)  # r2 = x x + y y
    add(r2, mul(y, y, out=b), out=r2)
    radial = mul(r2, k3)  # radial = 1 + r2 (k1 + r2 (k2 + r2 k3))
    add(k2, radial, out=radial)
    mul(r2, radial, out=radial)
    add(k1, radial, out=radial)
    mul(r2, radial, out=radial)
    add(1.0, radial, out=radial)
    two_p1_x = mul(2.0 * p1, x)  # shared by xd, yd and the derivatives
    two_p2_x = mul(2.0 * p2, x)
    xd = mul(x, radial)  # xd = x radial + (2 p1 x) y + p2 (r2 + 2 x x)
    add(xd, mul(two_p1_x, y, out=b), out=xd)
    mul(2.0, x, out=b)
    mul(b, x, out=b)
    add(r2, b, out=b)
    add(xd, mul(p2, b, out=b), out=xd)
    yd = mul(y, radial)  # yd = y radial + p1 (r2 + 2 y y) + (2 p2 x) y
    mul(2.0, y, out=b)
    mul(b, y, out=b)
    add(r2, b, out=b)
    add(yd, mul(p1, b, out=b), out=yd)
    add(yd, mul(two_p2_x, y, out=b), out=yd)
    return xd, yd, (r2, radial, two_p1_x, two_p2_x)


def _distort_derivatives(x, y, inter, dist):
    """d(xd)/dx, d(xd)/dy (which is d(yd)/dx) and d(yd)/dy from :func:`_distort`'s intermediates."""
    r2, radial, two_p1_x, two_p2_x = inter
    k1, k2, p1, p2, k3 = dist
    mul, add = np.multiply, np.add
    b0 = np.empty_like(x)
    dr = mul(3.0 * k3, r2)  # d(radial)/d(r2) = k1 + r2 (2 k2 + 3 k3 r2)
    add(2.0 * k2, dr, out=dr)
    mul(r2, dr, out=dr)
    add(k1, dr, out=dr)
    dxd_dx = mul(2.0, x)  # radial + 2 x x dr + 2 p1 y + 6 p2 x
    mul(dxd_dx, x, out=dxd_dx)
    mul(dxd_dx, dr, out=dxd_dx)
    add(radial, dxd_dx, out=dxd_dx)
    add(dxd_dx, mul(2.0 * p1, y, out=b0), out=dxd_dx)
    add(dxd_dx, mul(6.0 * p2, x, out=b0), out=dxd_dx)
    dxd_dy = mul(2.0, x)  # 2 x y dr + (2 p1 x) + 2 p2 y; also d(yd)/dx
    mul(dxd_dy, y, out=dxd_dy)
    mul(dxd_dy, dr, out=dxd_dy)
    add(dxd_dy, two_p1_x, out=dxd_dy)
    add(dxd_dy, mul(2.0 * p2, y, out=b0), out=dxd_dy)
    dyd_dy = mul(2.0, y)  # radial + 2 y y dr + 6 p1 y + (2 p2 x)
    mul(dyd_dy, y, out=dyd_dy)
    mul(dyd_dy, dr, out=dyd_dy)
    add(radial, dyd_dy, out=dyd_dy)
    add(dyd_dy, mul(6.0 * p1, y, out=b0), out=dyd_dy)
    add(dyd_dy, two_p2_x, out=dyd_dy)
    return dxd_dx, dxd_dy, dyd_dy


def _lens(dist):
    """[k1, k2, p1, p2, k3] of an OpenCV distortion vector (the first five terms)."""
    return np.asarray(dist, dtype=float).ravel()[:5]


def distort_normalised(xy, dist):
    """OpenCV's 5-term lens on normalised rays.

    Parameters
    ----------
    xy : ndarray, shape (..., 2)
        Undistorted normalised image coordinates (x / z, y / z in the camera frame C).
    dist : array_like, shape (5,)
        ``[k1, k2, p1, p2, k3]``.

    Returns
    -------
    xy_d : ndarray, shape (..., 2)
        Distorted normalised coordinates (pixels are ``K @ [xd, yd, 1]``).
    """
    xy = np.asarray(xy, dtype=float)
    x, y = np.atleast_1d(xy[..., 0]), np.atleast_1d(xy[..., 1])
    xd, yd, _ = _distort(x, y, _lens(dist))
    return np.stack([xd, yd], axis=-1).reshape(xy.shape)


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
    x = np.atleast_1d(p_C[..., 0] / p_C[..., 2])
    y = np.atleast_1d(p_C[..., 1] / p_C[..., 2])
    xd, yd, _ = _distort(x, y, _lens(dist))
    uv = np.stack([K[0, 0] * xd + K[0, 2], K[1, 1] * yd + K[1, 2]], axis=-1)
    return uv.reshape(p_C.shape[:-1] + (2,))


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
    lens = _lens(dist)
    iz = np.atleast_1d(1.0 / p_C[..., 2])
    x = p_C[..., 0] * iz
    y = p_C[..., 1] * iz
    xd, yd, inter = _distort(x, y, lens)
    a, b, d = _distort_derivatives(x, y, inter, lens)  # d(xd, yd)/d(x, y) = [[a, b], [b, d]]
    r2 = inter[0]
    r4 = r2 * r2
    xy = x * y
    uv = np.stack([fx * xd + K[0, 2], fy * yd + K[1, 2]], axis=-1)
    # d(x, y)/d(X, Y, Z) = [[1/Z, 0, -x/Z], [0, 1/Z, -y/Z]]
    J_p = np.zeros(x.shape + (2, 3))
    J_p[..., 0, 0] = fx * a * iz
    J_p[..., 0, 1] = fx * b * iz
    J_p[..., 0, 2] = -fx * (a * x + b * y) * iz
    J_p[..., 1, 0] = fy * b * iz
    J_p[..., 1, 1] = fy * d * iz
    J_p[..., 1, 2] = -fy * (b * x + d * y) * iz
    J_i = np.zeros(x.shape + (2, 9))
    J_i[..., 0, 0] = xd
    J_i[..., 1, 1] = yd
    J_i[..., 0, 2] = 1.0
    J_i[..., 1, 3] = 1.0
    J_i[..., 0, 4], J_i[..., 1, 4] = fx * x * r2, fy * y * r2
    J_i[..., 0, 5], J_i[..., 1, 5] = fx * x * r4, fy * y * r4
    J_i[..., 0, 6], J_i[..., 1, 6] = fx * 2.0 * xy, fy * (r2 + 2.0 * y * y)
    J_i[..., 0, 7], J_i[..., 1, 7] = fx * (r2 + 2.0 * x * x), fy * 2.0 * xy
    J_i[..., 0, 8], J_i[..., 1, 8] = fx * x * r4 * r2, fy * y * r4 * r2
    shape = p_C.shape[:-1]
    return uv.reshape(shape + (2,)), J_p.reshape(shape + (2, 3)), J_i.reshape(shape + (2, 9))


def project_poses(R_C_B, t_C_B, X_B, fx, fy, cx, cy, dist):
    """Project board points through a stack of board poses, keeping what the pose Jacobian needs.

    Parameters
    ----------
    R_C_B : ndarray, shape (N, 3, 3)
        Board rotations in the camera.
    t_C_B : ndarray, shape (N, 3)
        Board origins in the camera, metres.
    X_B : ndarray, shape (P, 3)
        Points in the board frame B, metres.
    fx, fy : float or ndarray, shape (N, 1)
        Focal lengths, px: one for all rows or one per row (many candidate focal lengths solved
        in one stack).
    cx, cy : float
        Principal point, px.
    dist : array_like, shape (5,)
        [k1, k2, p1, p2, k3].

    Returns
    -------
    uv_px : ndarray, shape (N, P, 2)
        Distorted pixels.
    xd, yd : ndarray, shape (N, P)
        Distorted normalised coordinates (d u / d fx and d v / d fy).
    parts : tuple of ndarray, each shape (N, P)
        The intermediates of :func:`pose_jacobian`; every one is per row, so indexing them all
        alike (``[v[rows] for v in parts]``) gives the Jacobian of those rows, bit for bit.
    """
    mul, add = np.multiply, np.add
    q = R_C_B @ X_B.T  # R X, (N, 3, P)
    qx, qy, qz = q[:, 0], q[:, 1], q[:, 2]
    inv_z = add(qz, t_C_B[:, 2:3])  # inv_z = 1 / (qz + tz)
    np.divide(1.0, inv_z, out=inv_z)
    x = add(qx, t_C_B[:, 0:1])  # x = (qx + tx) * inv_z
    mul(x, inv_z, out=x)
    y = add(qy, t_C_B[:, 1:2])
    mul(y, inv_z, out=y)
    xd, yd, inter = _distort(x, y, _lens(dist))
    uv = np.empty(x.shape + (2,))
    add(mul(fx, xd, out=uv[..., 0]), cx, out=uv[..., 0])  # u = fx xd + cx
    add(mul(fy, yd, out=uv[..., 1]), cy, out=uv[..., 1])
    return uv, xd, yd, (qx, qy, qz, inv_z, x, y, *inter)


def pose_jacobian(parts, fx, fy, dist):
    """d(u, v)/d(omega, t) of :func:`project_poses`, omega a left rotation increment.

    Parameters
    ----------
    parts : tuple of ndarray, each shape (N, P)
        :func:`project_poses`' intermediates (of all rows or of a subset, indexed alike).
    fx, fy : float or ndarray, shape (N, 1)
        The focal lengths of those rows, px.
    dist : array_like, shape (5,)
        [k1, k2, p1, p2, k3].

    Returns
    -------
    ndarray, shape (N, P, 2, 6)
        Derivatives of (u, v) w.r.t. (omega_x, omega_y, omega_z) of R <- exp([omega]x) R (px per
        rad) and w.r.t. t (px per metre).

    Notes
    -----
    The twelve components are written into contiguous planes and interleaved by one copy at
    the end: writing each straight into the (N, P, 2, 6) layout was twelve strided passes, a
    third of the Jacobian's time; the values are the same, only where they are stored differs.
    """
    qx, qy, qz, inv_z, x, y, *inter = parts
    mul, add, sub = np.multiply, np.add, np.subtract
    dxd_dx, dxd_dy, dyd_dy = _distort_derivatives(x, y, inter, _lens(dist))
    b1, b2 = np.empty_like(x), np.empty_like(x)
    planes = np.empty((2, 6) + x.shape)  # planes[row, k] = J[..., row, k]
    for row, (f, d_dx, d_dy) in enumerate(((fx, dxd_dx, dxd_dy), (fy, dxd_dy, dyd_dy))):
        # A = d(u or v)/dp (columns x, y, z of p): a0 = f d_dx inv_z, a1 = f d_dy inv_z,
        # a2 = -(f d_dx x + f d_dy y) inv_z
        # (evaluated in place in the translation columns 3, 4, 5 of the Jacobian, which they are)
        Jr = planes[row]
        a0, a1 = mul(f, d_dx, out=Jr[3]), mul(f, d_dy, out=Jr[4])
        a2 = add(mul(a0, x, out=Jr[5]), mul(a1, y, out=b1), out=Jr[5])
        mul(np.negative(a2, out=a2), inv_z, out=a2)
        mul(a0, inv_z, out=a0)
        mul(a1, inv_z, out=a1)
        # left perturbation R <- exp([w]x) R: dp/dw = -[q]x, so the row a^T (-[q]x) = (q x a)^T
        sub(mul(qy, a2, out=b1), mul(qz, a1, out=b2), out=Jr[0])
        sub(mul(qz, a0, out=b1), mul(qx, a2, out=b2), out=Jr[1])
        sub(mul(qx, a1, out=b1), mul(qy, a0, out=b2), out=Jr[2])
    return np.ascontiguousarray(planes.transpose(2, 3, 0, 1))
