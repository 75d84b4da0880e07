"""Calibration scores of predicted error covariances: band coverage and NEES.

:func:`band_multipliers` gives the half-widths of the 68.27 % and 95 % bands (normal or
Student-t); :func:`score_covariance` the share of errors inside them and the mean NEES
(6 for a calibrated six-dimensional prediction); :func:`nees_values` the NEES of each frame.
"""

from __future__ import annotations

import numpy as np
from scipy.stats import chi2
from scipy.stats import t as student_t

from cvsflow.metrics import ERROR_DIMS

#: Two-sided band multipliers of a normal: 68.27 % and 95 % (1.96 sigma).
BANDS = {"68": 1.0, "95": 1.959963984540054}
#: Working units of the fits and scores (mm, mrad): keeps the 6x6 covariances well conditioned.
WORKING_UNITS = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3])


def band_multipliers(model):
    """Half-widths of the 68.27 % and 95 % bands in predicted standard deviations.

    A normal model: 1 and 1.96. A Student-t model (``nu``): its quantiles over its standard
    deviation sqrt(nu / (nu - 2)) (narrower at 68 %, wider in the tails).

    Parameters
    ----------
    model : dict
        An error model (:func:`fit_error_model` or :func:`fit_transfer_model` output, or just
        ``{"nu": nu}``); its ``nu`` key, Student-t degrees of freedom (> 2), picks the
        distribution. Absent, None or non-finite: normal.

    Returns
    -------
    multipliers : dict
        ``{"68": k68, "95": k95}``: half-width of each two-sided band, in units of the
        predicted standard deviation (dimensionless; a band is ``mu +- k * sigma``).
    """
    nu = model.get("nu")
    if nu is None or not np.isfinite(nu):
        return dict(BANDS)
    sd = np.sqrt(nu / (nu - 2.0))
    return {"68": float(student_t.ppf(0.5 + 0.6826894921370859 / 2, nu) / sd),
            "95": float(student_t.ppf(0.975, nu) / sd)}


def score_covariance(cov, errors, nu=None, mean=None):
    """Calibration of predicted covariances on (held-out) frames.

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance, SI.
    errors : DataFrame
        ``err_{dim}`` of the same frames.
    nu : float, optional
        Student-t degrees of freedom of the prediction (the band quantiles); None: normal.
    mean : ndarray, shape (N, 6), optional
        Predicted error (the bands' centres), SI; default 0.

    Returns
    -------
    score : dict
        ``n``; ``inside_68``, ``inside_95`` per dimension and ``_all``; ``z_rms`` per
        dimension; ``nees_mean``, ``nees_inside_95`` (below the chi-square(6) 95 % quantile).
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    if mean is not None:
        E = E - mean
    sigma = np.sqrt(np.einsum("nii->ni", cov))
    Zs = E / sigma
    out = {"n": int(len(E))}
    for band, k in band_multipliers({"nu": nu}).items():
        inside = np.abs(Zs) <= k
        out[f"inside_{band}"] = {d: float(inside[:, j].mean()) for j, d in enumerate(ERROR_DIMS)}
        out[f"inside_{band}_all"] = float(inside.mean())
    out["z_rms"] = {d: float(np.sqrt(np.mean(Zs[:, j] ** 2))) for j, d in enumerate(ERROR_DIMS)}
    S = cov / np.outer(WORKING_UNITS, WORKING_UNITS)
    r = E / WORKING_UNITS
    nees = np.einsum("ni,ni->n", r, np.linalg.solve(S, r[:, :, None])[:, :, 0])
    out["nees_mean"] = float(nees.mean())
    out["nees_inside_95"] = float(np.mean(nees <= chi2.ppf(0.95, 6)))
    return out


def nees_values(cov, errors, mean=None):
    """Per-frame NEES e^T Sigma^-1 e (N,) of errors ``err_{dim}`` (minus ``mean``) under
    covariances (N, 6, 6).

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance of each frame, SI (m^2, m rad, rad^2), e.g.
        :func:`transfer_covariance`.
    errors : DataFrame
        ``err_{dim}`` for ``dim`` in ``ERROR_DIMS`` (``x_m, y_m, z_m`` in m, ``roll_rad,
        pitch_rad, yaw_rad`` in rad) of the same N frames, in the same order.
    mean : ndarray, shape (N, 6), optional
        Predicted error subtracted first (e.g. :func:`transfer_mean`), SI; None: zero.

    Returns
    -------
    nees : ndarray, shape (N,)
        Normalised estimation error squared, dimensionless (chi-square with 6 degrees of
        freedom for a calibrated normal prediction, mean 6). NaN for a frame whose error has
        a NaN.
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    E = (E if mean is None else E - mean) / WORKING_UNITS
    S = cov / np.outer(WORKING_UNITS, WORKING_UNITS)
    return np.einsum("ni,ni->n", E, np.linalg.solve(S, E[:, :, None])[:, :, 0])
