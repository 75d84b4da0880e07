"""Calibration scores of predicted error covariances: band coverage and NEES.

:func:`band_multipliers` gives the half-widths of the 68.27 % and 95 % bands (normal or
Student-t); :func:`score_covariance` the share of errors inside them and the mean NEES
(6 for a calibrated six-dimensional prediction); :func:`nees_values` the NEES of each frame.
"""

from __future__ import annotations

import numpy as np
from scipy.special import gammaincinv, gammaln, stdtrit, xlogy

from cvsflow.metrics import ERROR_DIMS

#: Two-sided band multipliers of a normal: 68.27 % and 95 % (1.96 sigma).
BANDS = {"68": 1.0, "95": 1.959963984540054}
#: Working units of the fits and scores (mm, mrad): keeps the 6x6 covariances well conditioned.
WORKING_UNITS = np.array([1e-3, 1e-3, 1e-3, 1e-3, 1e-3, 1e-3])


def chi2_quantile(p, df):
    """Chi-square quantile: ``scipy.stats.chi2.ppf(p, df)``, bit for bit, without scipy.stats.

    ``chi2.ppf`` is ``2 * scipy.special.gammaincinv(df / 2, p)``; calling it directly spares a
    job the import of scipy.stats (about 0.3 s of CPU per job).

    Parameters
    ----------
    p : float or ndarray
        Probability, in [0, 1].
    df : float or ndarray
        Degrees of freedom (> 0).

    Returns
    -------
    float or ndarray
        The value x with P(X <= x) = p for X chi-square with ``df`` degrees of freedom.
    """
    return 2.0 * gammaincinv(np.asarray(df) / 2, p)


def chi2_pdf(x, df):
    """Chi-square density at ``x`` (``scipy.stats.chi2.pdf`` to rounding), without scipy.stats.

    Parameters
    ----------
    x : float or ndarray
        Points (>= 0).
    df : float
        Degrees of freedom (> 0).

    Returns
    -------
    float or ndarray
        x^(df/2 - 1) exp(-x/2) / (2^(df/2) Gamma(df/2)); 0 for x < 0.
    """
    x = np.asarray(x, float)
    k = df / 2.0
    inside = x >= 0
    xs = np.where(inside, x, 1.0)
    log_f = xlogy(k - 1.0, xs) - xs / 2.0 - k * np.log(2.0) - gammaln(k)
    return np.where(inside, np.exp(log_f), 0.0)


def student_t_quantile(p, nu):
    """Student-t quantile: ``scipy.stats.t.ppf(p, nu)``, bit for bit, without scipy.stats.

    ``t.ppf`` is ``scipy.special.stdtrit(nu, p)``.

    Parameters
    ----------
    p : float or ndarray
        Probability, in [0, 1].
    nu : float or ndarray
        Degrees of freedom (> 0).

    Returns
    -------
    float or ndarray
        The value x with P(T <= x) = p for T Student-t with ``nu`` degrees of freedom.
    """
    return stdtrit(nu, p)


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
    return {"68": float(student_t_quantile(0.5 + 0.6826894921370859 / 2, nu) / sd),
            "95": float(student_t_quantile(0.975, nu) / sd)}


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
    out["nees_inside_95"] = float(np.mean(nees <= chi2_quantile(0.95, 6)))
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


def frame_runs(frame, fold=None):
    """Run label of each row: a run is consecutive frames (step 1) of one fold.

    Parameters
    ----------
    frame : array_like, shape (N,)
        Frame index of each row, in row order (int).
    fold : array_like, shape (N,), optional
        Cross-validation fold of each row; a change of fold starts a run. None: one fold.

    Returns
    -------
    runs : ndarray, shape (N,)
        Run label (int, 0, 1, ... in row order); rows t-1 and t are one run's neighbours
        exactly when their labels are equal.
    """
    frame = np.asarray(frame).astype(np.int64)
    fold = np.zeros(len(frame), np.int64) if fold is None else np.asarray(fold).astype(np.int64)
    start = np.r_[True, (np.diff(frame) != 1) | (fold[1:] != fold[:-1])]
    return np.cumsum(start) - 1


def standardised_errors(cov, errors, mean=None):
    """Errors over their predicted standard deviation per axis, z (N, 6), dimensionless.

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance, SI.
    errors : DataFrame
        ``err_{dim}`` of the same frames, SI.
    mean : ndarray, shape (N, 6), optional
        Predicted error (the bands' centres), SI; default 0.

    Returns
    -------
    z : ndarray, shape (N, 6)
        ``(err - mean) / sqrt(diag(cov))`` per axis of ``ERROR_DIMS``.
    """
    E = errors[[f"err_{d}" for d in ERROR_DIMS]].to_numpy(float)
    if mean is not None:
        E = E - mean
    return E / np.sqrt(np.einsum("nii->ni", cov))


def fit_ar1(z, runs, max_rho=0.95):
    """Lag-1 autocorrelation per axis of standardised errors within runs: an AR(1) fit.

    Parameters
    ----------
    z : ndarray, shape (N, 6)
        Standardised errors (:func:`standardised_errors`) of the fitting frames.
    runs : ndarray, shape (N,)
        :func:`frame_runs` of the same rows (neighbours across a run break are not paired).
    max_rho : float
        Upper clip of the coefficient (dimensionless, < 1); the lower clip is 0.

    Returns
    -------
    rho : ndarray, shape (6,)
        AR(1) coefficient of each axis in ``[0, max_rho]``; 0 where no two rows are neighbours.
    """
    same = runs[1:] == runs[:-1]
    a, b = z[:-1][same], z[1:][same]
    if not len(a):
        return np.zeros(z.shape[1])
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.sum(a * b, axis=0) / np.sqrt(np.sum(a * a, axis=0) * np.sum(b * b, axis=0))
    return np.clip(np.nan_to_num(rho), 0.0, max_rho)


def ar1_innovations(z, runs, rho):
    """AR(1)-whitened standardised errors: (z_t - rho z_{t-1}) / sqrt(1 - rho^2) within a run.

    Under an AR(1) with unit marginal variance and coefficient rho (per axis) the result is
    independent from frame to frame with the marginal's variance; a run's first row has no
    predecessor and is kept as it is.

    Parameters
    ----------
    z : ndarray, shape (N, 6)
        Standardised errors.
    runs : ndarray, shape (N,)
        :func:`frame_runs` of the rows.
    rho : array_like, shape (6,) or scalar
        AR(1) coefficient per axis, in [0, 1).

    Returns
    -------
    innovations : ndarray, shape (N, 6)
        Dimensionless.
    """
    rho = np.broadcast_to(np.asarray(rho, float), (z.shape[1],))
    out = z.copy()
    same = np.r_[False, runs[1:] == runs[:-1]]
    out[same] = (z[same] - rho * z[np.flatnonzero(same) - 1]) / np.sqrt(1.0 - rho**2)
    return out


def block_mean_variance(n, rho):
    """Variance of the mean of n consecutive AR(1) values of unit variance: (1/n^2) sum rho^|i-j|.

    Parameters
    ----------
    n : int
        Block length, frames (>= 1).
    rho : array_like, shape (K,) or scalar
        AR(1) coefficient(s), in [0, 1).

    Returns
    -------
    var : ndarray, shape (K,) or float
        Dimensionless; 1 / n for rho = 0.
    """
    rho = np.asarray(rho, float)
    lag = np.arange(1, n)
    return (n + 2.0 * np.sum((n - lag) * rho[..., None] ** lag, axis=-1)) / n**2


def score_time_correlated(cov, errors, rho, runs, nu=None, mean=None, block_frames=15):
    """Band coverage and NEES of the errors whitened by an AR(1) in time (a fitted ``rho``).

    A per-frame covariance says nothing of how a frame's error follows the previous one;
    with errors that come in runs, a fold's share inside a band then scatters far more than
    a binomial's. Here each axis's standardised error is whitened by the AR(1)
    (:func:`ar1_innovations`) before it is scored, so the scores test the per-frame
    covariance together with the time correlation, frame by frame. The NEES is that of the
    whitened vector under the frame's correlation matrix, ``zeta^T R^-1 zeta`` (exact when
    the correlation matrix is constant over neighbouring frames and rho is the same on every
    axis). Blocks of ``block_frames`` consecutive frames of a run add the RMS of their mean
    standardised error over its AR(1) standard deviation (:func:`block_mean_variance`; 1 for
    a calibrated model, above 1 when the errors are more persistent than the AR(1)).

    Parameters
    ----------
    cov : ndarray, shape (N, 6, 6)
        Predicted error covariance, SI.
    errors : DataFrame
        ``err_{dim}`` of the same frames, SI.
    rho : array_like, shape (6,)
        AR(1) coefficient per axis of ``ERROR_DIMS``, fitted on other frames than these
        (:func:`fit_ar1`).
    runs : ndarray, shape (N,)
        :func:`frame_runs` of the rows.
    nu : float, optional
        Student-t degrees of freedom of the prediction (the band quantiles); None: normal.
    mean : ndarray, shape (N, 6), optional
        Predicted error, SI; default 0.
    block_frames : int
        Frames per block of the block-mean score.

    Returns
    -------
    score : dict
        ``n``; ``rho`` per axis; ``inside_68``, ``inside_95`` per dimension and ``_all`` and
        ``z_rms`` per dimension, all of the whitened errors; ``nees_mean``,
        ``nees_inside_95``; ``block_z_rms`` per dimension and ``n_blocks``.
    """
    rho = np.broadcast_to(np.asarray(rho, float), (6,))
    runs = np.asarray(runs)
    z = standardised_errors(cov, errors, mean)
    w = ar1_innovations(z, runs, rho)
    out = {"n": int(len(z)), "rho": {d: float(rho[j]) for j, d in enumerate(ERROR_DIMS)}}
    for band, k in band_multipliers({"nu": nu}).items():
        inside = np.abs(w) <= k
        out[f"inside_{band}"] = {d: float(inside[:, j].mean()) for j, d in enumerate(ERROR_DIMS)}
        out[f"inside_{band}_all"] = float(inside.mean())
    out["z_rms"] = {d: float(np.sqrt(np.mean(w[:, j] ** 2))) for j, d in enumerate(ERROR_DIMS)}
    sd = np.sqrt(np.einsum("nii->ni", cov))
    R = cov / (sd[:, :, None] * sd[:, None, :])
    nees = np.einsum("ni,ni->n", w, np.linalg.solve(R, w[:, :, None])[:, :, 0])
    out["nees_mean"] = float(nees.mean())
    out["nees_inside_95"] = float(np.mean(nees <= chi2_quantile(0.95, 6)))
    means = []
    for r in np.unique(runs):
        zr = z[runs == r]
        for b in range(len(zr) // block_frames):
            means.append(zr[b * block_frames:(b + 1) * block_frames].mean(axis=0))
    out["n_blocks"] = len(means)
    if means:
        m = np.array(means) / np.sqrt(block_mean_variance(block_frames, rho))
        out["block_z_rms"] = {d: float(np.sqrt(np.mean(m[:, j] ** 2))) for j, d in enumerate(ERROR_DIMS)}
    else:
        out["block_z_rms"] = {d: float("nan") for d in ERROR_DIMS}
    return out


def fit_multivariate_t(r, nu_grid=None, n_iter=100, tol=1e-8):
    """Maximum-likelihood multivariate Student-t (mean zero) of residual rows: covariance and nu.

    For each nu of the grid the scale matrix is the EM fixed point (weights
    ``(nu + p) / (nu + d_i)``, ``d_i`` the rows' squared Mahalanobis distances); the nu of the
    highest log-likelihood is kept. A Gaussian's tails are the grid's largest nu.

    Parameters
    ----------
    r : ndarray, shape (N, p)
        Residual rows (any units), N > p.
    nu_grid : array_like, optional
        Degrees of freedom tried (> 2); default 30 values from 2.5 to 300, geometric.
    n_iter : int
        Most EM rounds per nu.
    tol : float
        Relative change of the scale matrix at which EM stops.

    Returns
    -------
    cov : ndarray, shape (p, p)
        The fitted distribution's covariance, ``scale * nu / (nu - 2)``.
    nu : float
        Its degrees of freedom.
    """
    r = np.asarray(r, float)
    n, p = r.shape
    grid = np.geomspace(2.5, 300.0, 30) if nu_grid is None else np.asarray(nu_grid, float)
    S0 = r.T @ r / n
    best = (-np.inf, None, None)
    for nu in grid:
        S = S0.copy()
        for _ in range(n_iter):
            d = np.einsum("ni,ij,nj->n", r, np.linalg.inv(S), r)
            w = (nu + p) / (nu + d)
            S_new = (r * w[:, None]).T @ r / n
            done = np.max(np.abs(S_new - S)) <= tol * np.max(np.abs(S))
            S = S_new
            if done:
                break
        d = np.einsum("ni,ij,nj->n", r, np.linalg.inv(S), r)
        ll = n * (gammaln((nu + p) / 2) - gammaln(nu / 2) - 0.5 * p * np.log(nu * np.pi)
                  - 0.5 * np.linalg.slogdet(S)[1]) - 0.5 * (nu + p) * np.log1p(d / nu).sum()  # fmt: skip
        if ll > best[0]:
            best = (ll, S, float(nu))
    _, S, nu = best
    return S * nu / (nu - 2.0), nu
