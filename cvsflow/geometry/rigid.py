"""Least-squares rigid fits of corresponding point sets (Kabsch/Umeyama, no scale)."""

from __future__ import annotations

import numpy as np

from cvsflow.geometry.transforms import make_T


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


def fit_rigid_pair(p_src, p_dst):
    """Least-squares rigid transform T_dst_src with p_dst ~ T_dst_src p_src, one point set.

    Parameters
    ----------
    p_src, p_dst : ndarray, shape (M, 3)
        Corresponding points in frames src and dst, metres; M >= 3, not collinear, all finite.

    Returns
    -------
    T_dst_src : ndarray, shape (4, 4)

    Notes
    -----
    The same Kabsch/Umeyama solution as :func:`fit_rigid` for one unweighted point set,
    without its checks. The two differ only in summation order (this one's cross-covariance
    and translation are plain matrix products, :func:`fit_rigid`'s are einsums), i.e. in the
    last bits (~5e-16 on unit-sized points). The rendered demo's truth (``synth.markers``) was
    made with this one; folding it into :func:`fit_rigid` changes the rendered truth in its
    last bits, so it waits for a change that may alter the demo's tables.
    """
    c_src, c_dst = p_src.mean(axis=0), p_dst.mean(axis=0)
    H = (p_src - c_src).T @ (p_dst - c_dst)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    return make_T(R, c_dst - R @ c_src)
