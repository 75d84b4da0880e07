"""Least-squares rigid fits of corresponding point sets: batched and weighted (:func:`fit_rigid`),
or one set with scale (:func:`umeyama`)."""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry.transforms import make_T, project_SO3


def fit_rigid(P_body, Q_world, weights=None):
    """Least-squares rigid transforms mapping body-frame points onto observed points, per frame.

    Parameters
    ----------
    P_body : ndarray, shape (M, 3) or (N, M, 3)
        Marker layout in the body frame, metres.
    Q_world : ndarray, shape (N, M, 3)
        Observed marker positions in W, metres; NaN rows are ignored.
    weights : ndarray, shape (N, M), optional
        Non-negative weights; default 1 where ``Q_world`` is finite, else 0.

    Returns
    -------
    T_W_body : ndarray, shape (N, 4, 4)
        Fitted transforms (NaN where fewer than three non-collinear markers are usable).
    rms_m : ndarray, shape (N,)
        RMS distance between observed and fitted markers over the used markers, metres.
    n_used : ndarray of int, shape (N,)
        Markers used per frame.

    Notes
    -----
    Kabsch/Umeyama without scale (Umeyama 1991, eqs. 38-41), vectorised with numpy's batched
    SVD. The sign correction ``diag(1, 1, det(V U^T))`` guards against reflections.
    """
    Q = np.asarray(Q_world, dtype=float)
    N, M = Q.shape[:2]
    P = np.broadcast_to(np.asarray(P_body, dtype=float), (N, M, 3))
    finite = np.isfinite(Q).all(axis=2)
    w = finite.astype(float) if weights is None else np.where(finite, weights, 0.0)
    Qz = np.where(finite[..., None], Q, 0.0)
    n_used = (w > 0).sum(axis=1)
    wsum = np.maximum(w.sum(axis=1), 1e-300)[:, None]
    cP = (w[..., None] * P).sum(axis=1) / wsum
    cQ = (w[..., None] * Qz).sum(axis=1) / wsum
    Pc = P - cP[:, None]
    Qc = Qz - cQ[:, None]
    H = np.einsum("nm,nmi,nmj->nij", w, Pc, Qc)  # Umeyama eq. 38 (cross-covariance)
    U, S, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.swapaxes(Vt, 1, 2) @ np.swapaxes(U, 1, 2)))
    d[d == 0] = 1.0
    D = np.zeros((N, 3, 3))
    D[:, 0, 0] = 1.0
    D[:, 1, 1] = 1.0
    D[:, 2, 2] = d
    R = np.swapaxes(Vt, 1, 2) @ D @ np.swapaxes(U, 1, 2)  # Umeyama eq. 40
    t = cQ - np.einsum("nij,nj->ni", R, cP)  # Umeyama eq. 41
    resid = Qz - (np.einsum("nij,nmj->nmi", R, P) + t[:, None])
    rms = np.sqrt((w * (resid**2).sum(axis=2)).sum(axis=1) / wsum[:, 0])
    # three markers on a line fix no rotation about that line
    scale = np.maximum(S[:, 0], 1e-300)
    ok = (n_used >= 3) & (S[:, 1] > 1e-8 * scale) & np.isfinite(R).all(axis=(1, 2))
    T = make_T(R, t)
    T[~ok] = np.nan
    rms[~ok] = np.nan
    return T, rms, n_used


def umeyama(p_src, p_dst, with_scale=False):
    """Least-squares similarity (or rigid) transform of one point set: p_dst ~ s R p_src + t.

    Parameters
    ----------
    p_src, p_dst : ndarray, shape (M, 3)
        Corresponding points in frames src and dst, metres; M >= 3, not collinear, all finite.
    with_scale : bool
        Sim(3) (s fitted) when True, SE(3) (s = 1) otherwise.

    Returns
    -------
    T_dst_src : ndarray, shape (4, 4)
        The rigid part (R, t), metres.
    scale : float
        s (1.0 without ``with_scale``).

    Raises
    ------
    OptimiseError
        All source points on one spot.

    Notes
    -----
    Umeyama, "Least-squares estimation of transformation parameters between two point
    patterns", IEEE TPAMI 13(4), 1991, eqs. 36-42 (evo's ``core.geometry.umeyama_alignment``):
    the rotation is the nearest rotation (:func:`cvsflow.geometry.project_SO3`, eqs. 39-40) to
    the cross-covariance. :func:`fit_rigid` is the batched, weighted form without scale.
    """
    x = np.asarray(p_src, dtype=float)
    y = np.asarray(p_dst, dtype=float)
    n = len(x)
    mx, my = x.mean(0), y.mean(0)
    xc, yc = x - mx, y - my
    sigma_x = np.sum(xc**2) / n  # eq. 36
    if not sigma_x > 0:
        raise OptimiseError(f"umeyama: all {n} source points coincide; nothing to fit")
    cov = yc.T @ xc / n  # eq. 38
    R = project_SO3(cov)  # eqs. 39, 40
    s = 1.0
    if with_scale:  # eq. 42: trace(D S) / sigma_x, the smallest value signed as the reflection test
        d = np.linalg.svd(cov, compute_uv=False)
        s = float((d[0] + d[1] + (d[2] if np.linalg.det(cov) >= 0 else -d[2])) / sigma_x)
    t = my - s * R @ mx  # eq. 41
    return make_T(R, t), s
