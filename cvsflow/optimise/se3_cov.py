"""Parameter covariance of the ``se3`` estimate: data-only and from the fixed intrinsics.

Data only: the Gauss-Newton covariance of an M-estimator (Huber 1981, sec. 7.6)
``sigma_eff^2 (J^T J)^-1`` and a cluster-robust sandwich ``H^-1 (sum_c g_c g_c^T) H^-1`` over
contiguous time blocks (:func:`covariances`). The intrinsics held fixed carry their
calibration uncertainty into the free estimates through the sensitivity
``S = -(J^T W J)^-1 J^T W J_fixed`` (:func:`fixed_sensitivity`; see
:func:`cvsflow.optimise.se3.optimise_se3`, Notes).
"""

from __future__ import annotations

import logging
from typing import NamedTuple

import numpy as np

from cvsflow.metrics import cluster_dof, leverage_corrected_scores
from cvsflow.optimise.se3_lm import gram, loss_weights

log = logging.getLogger(__name__)

#: 1-sigma of each intrinsic held fixed when camera.yaml has no ``std`` (px for fx..cy, then
#: unitless): a 15-still 640 x 480 calibration at 0.1-0.4 px RMS, rounded up (the demo's stills
#: give 0.3, 0.3, 0.6, 0.5 px, 0.003, 0.03, 2e-4, 2e-4, 0.08; OpenCV's 13 sample stills 0.9,
#: 1.0, 1.0, 1.1 px, 0.012, 0.09, 2e-4, 3e-4, 0.2).
DEFAULT_INTRINSIC_STD = {"fx": 1.0, "fy": 1.0, "cx": 1.0, "cy": 1.0, "k1": 0.01, "k2": 0.05,
                         "p1": 5e-4, "p2": 5e-4, "k3": 0.1}  # fmt: skip


class SandwichCovariance(NamedTuple):
    """:func:`covariances`' result (see there)."""

    cov_gn: np.ndarray
    cov_cl: np.ndarray
    JtJ_inv: np.ndarray
    sigma2: float
    n_clusters: int
    dof: np.ndarray


def covariances(J, r, loss, f_scale, clusters, adjacent=False):
    """Gauss-Newton M-estimator covariance, cluster-robust sandwich, and (J^T J)^-1.

    Parameters
    ----------
    J : ndarray, shape (m, n)
        Jacobian of the residuals at the solution.
    r : ndarray, shape (m,)
        Residuals at the solution, px.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale, px.
    clusters : array_like, shape (m,)
        Cluster label of each residual (e.g. its time block).
    adjacent : bool
        Clusters are consecutive time blocks (integer labels): add the cross terms of
        neighbouring blocks to the meat, ``sum_c (g_c g_c+1^T + g_c+1 g_c^T)``, projected onto
        the positive semi-definite cone. Errors correlated across a block boundary are missed by
        the block sum alone: with AR(1) errors of correlation time tau it lacks about 2 tau / L
        of the variance for blocks of length L.

    Returns
    -------
    SandwichCovariance
        ``cov_gn`` (n, n): ``sigma_eff^2 (J^T J)^-1``, sigma_eff^2 = m/(m-n) mean(psi^2) /
        mean(psi')^2; ``cov_cl`` (n, n): the cluster-robust sandwich ``H^-1 (sum_c g_c g_c^T)
        H^-1`` with each cluster's score g_c corrected for its leverage (CR2,
        :func:`cvsflow.metrics.sandwich.leverage_corrected_scores` with power 1/2);
        ``JtJ_inv`` (n, n): pseudo-inverse of J^T J; ``sigma2``: sigma_eff^2, px^2;
        ``n_clusters``; ``dof`` (n,): the sandwich's degrees of freedom per parameter
        (:func:`cvsflow.metrics.sandwich.cluster_dof`).
    """
    m, n = J.shape
    psi, dpsi = loss_weights(r, loss, f_scale)
    JtJ = gram(J)
    JtJ_inv = np.linalg.pinv(JtJ)
    # Huber (1981) eq. 7.6.x: sigma_eff^2 = m/(m-n) mean(psi^2) / mean(psi')^2
    sigma2 = (m / max(m - n, 1)) * np.mean(psi**2) / np.mean(dpsi) ** 2
    cov_gn = sigma2 * JtJ_inv
    H = gram(J, dpsi)
    H_inv = np.linalg.pinv(H)
    g_rows = J * psi[:, None]
    labels, inv = np.unique(clusters, return_inverse=True)
    G = len(labels)
    g_c = np.zeros((G, n))
    np.add.at(g_c, inv, g_rows)
    # CR2 (Bell and McCaffrey 2002): each cluster's score scaled by (I - H_c H^-1)^-1/2,
    # which makes the meat unbiased for independent errors however few the clusters. The
    # plain CR1 sandwich was 20-36 % short with the 10-12 one-second blocks of a 12 s session;
    # CR3 (the jackknife, power 1) was as much too wide with 8 blocks or a rig's 30 parameters
    # (docs/findings.md, "se3's standard errors").
    order = np.argsort(inv, kind="stable")
    bounds = np.searchsorted(inv[order], np.arange(G + 1))
    H_c = np.stack([gram(J[rows], dpsi[rows]) for rows in np.split(order, bounds[1:-1])])
    g_c = leverage_corrected_scores(g_c, H_c, H, power=0.5)[0]
    meat = gram(g_c)
    nb = np.flatnonzero(np.diff(labels) == 1) if adjacent else None
    if adjacent:
        cross = g_c[nb].T @ g_c[nb + 1]
        lam, V = np.linalg.eigh(meat + cross + cross.T)
        meat = (V * np.clip(lam, 0.0, None)) @ V.T
    cov_cl = H_inv @ meat @ H_inv
    return SandwichCovariance(cov_gn, cov_cl, JtJ_inv, float(sigma2), G, cluster_dof(H_inv, H_c, nb))


def fixed_intrinsic_std(camera, names):
    """1-sigma of the fixed intrinsics ``names``: camera["std"], else DEFAULT_INTRINSIC_STD.

    Parameters
    ----------
    camera : dict
        camera.yaml content; its optional ``std`` maps a name to a 1-sigma.
    names : sequence of str
        Intrinsics held fixed.

    Returns
    -------
    std : ndarray, shape (k,)
        px for fx..cy, unitless for the distortion terms.
    defaulted : list of str
        Names whose std is missing or not a finite value >= 0, taken from the default.
    """
    given = camera.get("std") if isinstance(camera, dict) else None
    given = given if isinstance(given, dict) else {}
    sd, defaulted = [], []
    for n in names:
        v = given.get(n)
        try:
            v = float(v)
        except (TypeError, ValueError):
            v = float("nan")
        if not (np.isfinite(v) and v >= 0.0):
            v = DEFAULT_INTRINSIC_STD[n]
            defaulted.append(n)
        sd.append(v)
    return np.array(sd, float), defaulted


def fixed_sensitivity(J, J_fixed, r, loss, f_scale):
    """S = d x_hat / d theta_fixed = -(J^T W J)^-1 J^T W J_fixed, W = diag psi'(r).

    Parameters
    ----------
    J : ndarray, shape (m, n)
        Jacobian w.r.t. the free parameters.
    J_fixed : ndarray, shape (m, k)
        Jacobian w.r.t. the fixed intrinsics.
    r : ndarray, shape (m,)
        Residuals, px.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale, px.

    Returns
    -------
    S : ndarray, shape (n, k)
    """
    dpsi = loss_weights(r, loss, f_scale)[1]
    H = gram(J, dpsi)
    B = np.einsum("mi,m,mj->ij", J, dpsi, J_fixed, optimize=False)
    return -np.linalg.pinv(H) @ B


def correlation(cov):
    """Correlation matrix of a covariance.

    Parameters
    ----------
    cov : ndarray, shape (n, n)

    Returns
    -------
    corr : ndarray, shape (n, n)
        cov_ij / (s_i s_j), s the standard deviations (floored at 1e-150).
    """
    d = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
    return cov / np.outer(d, d)


def parameter_covariance(J, r, loss, f_scale, clusters, J_fixed, sd_fixed):
    """Data-only and total covariance of an se3 estimate: the one recipe mono and rig share.

    The data-only standard errors are the larger of the Gauss-Newton and the cluster-robust
    ones per parameter, with the correlations of ``(J^T J)^-1``; the fixed intrinsics add
    ``S Sigma_theta S^T`` (``Sigma_theta = diag(sd_fixed^2)``, :func:`fixed_sensitivity`).

    Parameters
    ----------
    J : ndarray, shape (m, n)
        Jacobian of the residuals at the solution (free parameters).
    r : ndarray, shape (m,)
        Residuals, px.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale, px.
    clusters : array_like, shape (m,)
        Cluster label (time block) of each residual.
    J_fixed : ndarray, shape (m, k)
        Jacobian w.r.t. the intrinsics held fixed (k may be 0).
    sd_fixed : ndarray, shape (k,)
        Their 1-sigma.

    Returns
    -------
    cov : dict
        ``se_gn``, ``se_cl``, ``se_data``, ``se_fixed``, ``se`` (n,); ``corr`` (data only,
        from (J^T J)^-1), ``cov_data``, ``cov_fixed``, ``cov_total``, ``corr_total`` (n, n);
        ``S`` (n, k); ``sigma2`` (px^2), ``n_clusters``.
    """
    cov_gn, cov_cl, JtJ_inv, sigma2, n_clusters, _ = covariances(J, r, loss, f_scale, clusters)
    se_gn = np.sqrt(np.diag(cov_gn))
    se_cl = np.sqrt(np.diag(cov_cl))
    se_data = np.maximum(se_gn, se_cl)
    corr = correlation(JtJ_inv)
    cov_data = corr * np.outer(se_data, se_data)
    if J_fixed.shape[1]:
        S = fixed_sensitivity(J, J_fixed, r, loss, f_scale)
        cov_fixed = (S * sd_fixed**2) @ S.T
    else:
        S = np.zeros((J.shape[1], 0))
        cov_fixed = np.zeros_like(cov_data)
    se_fixed = np.sqrt(np.clip(np.diag(cov_fixed), 0.0, None))
    cov_total = cov_data + cov_fixed
    return {
        "se_gn": se_gn, "se_cl": se_cl, "se_data": se_data, "se_fixed": se_fixed,
        "se": np.sqrt(np.diag(cov_total)), "corr": corr, "cov_data": cov_data,
        "cov_fixed": cov_fixed, "cov_total": cov_total, "corr_total": correlation(cov_total),
        "S": S, "sigma2": sigma2, "n_clusters": n_clusters,
    }  # fmt: skip


#: The video's principal point and the stills' disagree when they differ by more than this
#: many combined standard errors.
PRINCIPAL_POINT_Z_WARN = 3.0


def principal_point_warnings(camera: dict, names, x, se) -> list[str]:
    """Warnings (logged) where the fit's free cx or cy disagrees with the stills' calibration.

    Parameters
    ----------
    camera : dict
        camera.yaml content: ``K`` (the stills' cx, cy) and ``std`` (their 1-sigma, px).
    names : sequence of str
        The fit's parameter names (``cx``, ``cy`` among them when free).
    x, se : ndarray, shape (n,)
        The estimates and their standard errors, in the order of ``names``.

    Returns
    -------
    list of str
        One per disagreeing coordinate: both values, their sigmas and the z.
    """
    K = np.asarray(camera["K"], float)
    std = camera.get("std") or {}
    out = []
    for name, stills in (("cx", K[0, 2]), ("cy", K[1, 2])):
        if name not in names or std.get(name) is None:
            continue
        k = list(names).index(name)
        sd = float(np.hypot(se[k], std[name]))
        z = (x[k] - stills) / sd
        if abs(z) > PRINCIPAL_POINT_Z_WARN:
            msg = (f"se3: the video puts {name} at {x[k]:.2f} +- {se[k]:.2f} px, the stills' "
                   f"calibration at {stills:.2f} +- {std[name]:.2f} px ({z:+.1f} combined sigma, "
                   f"warned above {PRINCIPAL_POINT_Z_WARN:g}): the stills' principal point is "
                   "off (look at camera.yaml's outliers and cross_validation) or the lens moved "
                   "between the stills and the video")
            out.append(msg)
            log.warning(msg)
    return out

