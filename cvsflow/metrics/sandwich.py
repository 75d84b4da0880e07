"""Cluster-robust sandwich covariance of an M-estimator with few, unequal clusters.

The sandwich ``H^-1 (sum_c s_c s_c^T) H^-1`` (Huber 1967) over clusters c of rows that share
an error (a time block of frames: the Vicon noise and the corner errors of neighbouring
frames persist) is biased low when the clusters are few or one of them carries much of H:
the fit follows that cluster's residuals, which then understate its error. CR3 (the one-step
delete-one-cluster jackknife; MacKinnon, Nielsen and Webb 2023, "Fast and reliable jackknife
and bootstrap methods for cluster-robust inference") undoes each cluster's leverage first:
``H^-1 (I - H_c H^-1)^-1 s_c`` is the one-step change of the solution when c is left out.
CR2 (Bell and McCaffrey 2002; Pustejovsky and Tipton 2018) takes the square root of that
correction and is unbiased for independent errors.

Used by the se3 fit (CR2, :mod:`cvsflow.optimise.se3_cov`), the flight clock (CR3,
:mod:`cvsflow.flight.clock`) and the hand-eye from pose streams (CR2 with neighbouring blocks and
:func:`cluster_dof`, :mod:`cvsflow.handeye.stream_fit`).
"""

from __future__ import annotations

import numpy as np


def leverage_corrected_scores(S, H_c, H=None, power=1.0):
    """Each cluster's score with its leverage undone: ``H^1/2 (I - A_c)^-power H^-1/2 s_c``.

    ``A_c = H^-1/2 H_c H^-1/2`` is the cluster's share of the information in symmetric form.
    With ``power=1`` (CR3), ``H^-1`` times the result is ``(H - H_c)^-1 s_c``, the one-step
    change of the solution when cluster c is left out. With ``power=0.5`` (CR2, Bell and
    McCaffrey 2002) the meat ``sum s~ s~^T`` is unbiased for independent errors; CR3 is wider
    still, too wide when the clusters are barely more than the parameters. The eigenvalues of
    ``1 - A_c`` are floored at 1e-3, for a cluster that alone determines some direction.

    Parameters
    ----------
    S : ndarray, shape (C, P)
        Score sum of each cluster, ``sum J_i^T psi(r_i)`` over its rows.
    H_c : ndarray, shape (C, P, P)
        Each cluster's part of H, ``sum psi'(r_i) J_i^T J_i`` over its rows.
    H : ndarray, shape (P, P), optional
        The whole H; default ``H_c.sum(axis=0)``.
    power : float
        1 (CR3, the jackknife) or 0.5 (CR2).

    Returns
    -------
    S_corrected : ndarray, shape (C, P)
    lam, V : ndarray, shapes (P,), (P, P)
        Eigen-decomposition of H (``H^-1 = (V / lam) @ V.T``), eigenvalues floored at 1e-15 of
        the largest (a direction the data do not fix has no leverage to undo).
    """
    lam, V = np.linalg.eigh(H_c.sum(axis=0) if H is None else H)
    lam = np.maximum(lam, lam.max() * 1e-15)
    H_half, H_mhalf = (V * lam**0.5) @ V.T, (V * lam**-0.5) @ V.T
    out = np.array(S, float, copy=True)
    for c in range(len(out)):
        lev, U = np.linalg.eigh(H_mhalf @ H_c[c] @ H_mhalf)
        out[c] = H_half @ ((U / np.maximum(1 - lev, 1e-3) ** power) @ U.T) @ H_mhalf @ out[c]
    return out, lam, V


def cluster_dof(H_inv, H_c, adjacent=None):
    """Effective degrees of freedom of each parameter's cluster-robust variance (Satterthwaite).

    Parameter p's sandwich variance is a sum over clusters of ``u_c^2``, ``u_c = a_p^T s_c``
    with ``a_p`` row p of ``H^-1`` (plus ``2 u_c u_c+1`` over neighbouring time blocks when
    their cross terms are in the meat). Under the working model the ``u_c`` are independent
    with variances proportional to ``v_c = a_p^T H_c a_p`` (the cluster's share of the
    information in that direction), so the sum has mean ``sum v_c`` and variance
    ``2 (sum v_c^2 + 2 sum v_c v_c+1)``, and is about ``chi2(nu) / nu`` times its mean with
    ``nu = (sum_c v_c)^2 / (sum_c v_c^2 + 2 sum_adjacent v_c v_c+1)`` (Satterthwaite 1946; the
    working-model approximation of Bell and McCaffrey 2002, Pustejovsky and Tipton 2018). ``nu``
    is the number of clusters when they inform the parameter alike (about a third of it with
    the neighbours' cross terms) and falls towards 1 when a few clusters carry its information.

    Parameters
    ----------
    H_inv : ndarray, shape (P, P)
        Inverse of the whole curvature H.
    H_c : ndarray, shape (C, P, P)
        Each cluster's part of H.
    adjacent : ndarray of int, optional
        Indices c whose cluster c + 1 is its neighbour (their cross terms are in the meat).

    Returns
    -------
    nu : ndarray, shape (P,)
        Degrees of freedom per parameter, in [1, C].
    """
    v = np.clip(np.einsum("pi,cij,pj->cp", H_inv, H_c, H_inv, optimize=False), 0.0, None)
    den = (v**2).sum(axis=0)
    if adjacent is not None and len(adjacent):
        den = den + 2.0 * (v[adjacent] * v[np.asarray(adjacent) + 1]).sum(axis=0)
    return np.clip(v.sum(axis=0) ** 2 / np.maximum(den, 1e-300), 1.0, len(H_c))
