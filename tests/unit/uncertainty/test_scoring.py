"""cvsflow.uncertainty.scoring: the multivariate Student-t fit of residual rows."""

import numpy as np

from cvsflow.uncertainty import fit_multivariate_t


def test_fit_multivariate_t_recovers_nu_and_covariance():
    """Draws of a 6-d Student-t (nu 4) give back nu within a factor 1.5 and the covariance within
    15 %; Gaussian draws give a large nu."""
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    C = A @ A.T + 6 * np.eye(6)
    L = np.linalg.cholesky(C * (4 - 2) / 4)  # scale of a t with covariance C
    z = rng.normal(size=(4000, 6)) @ L.T / np.sqrt(rng.chisquare(4, size=(4000, 1)) / 4)
    cov, nu = fit_multivariate_t(z)
    assert 4 / 1.5 < nu < 4 * 1.5
    assert np.allclose(np.diag(cov), np.diag(C), rtol=0.15)
    _, nu_gauss = fit_multivariate_t(rng.normal(size=(4000, 6)) @ np.linalg.cholesky(C).T)
    assert nu_gauss > 30
