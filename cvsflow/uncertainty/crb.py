"""The Cramer-Rao floor of a frame's pose error from its corner noise alone."""

from __future__ import annotations

import numpy as np

from cvsflow.uncertainty.propagation import cov_from_columns


def cramer_rao_sigma(features, sigma_px):
    """Cramer-Rao standard deviation of each frame's pose error from the corner noise alone.

    The PnP pose is the ML estimate under iid Gaussian corner noise of ``sigma_px`` per axis,
    whose covariance is bounded below by sigma_px^2 (J^T J)^-1 (the Fisher information of the
    corners the frame saw), pushed to the error dimensions: the physical floor of a frame.

    Parameters
    ----------
    features : DataFrame
        :func:`measurement_features` of the frames (their ``unitcov_{a}{b}`` columns, the
        error covariance per px^2 of corner noise).
    sigma_px : float or array_like, shape (N,)
        Corner noise per image axis, px: one value for all frames or one per frame.

    Returns
    -------
    crb : ndarray, shape (N, 6)
        m for x, y, z; rad for roll, pitch, yaw.
    """
    U = cov_from_columns(features, "unitcov")
    sig = np.broadcast_to(np.asarray(sigma_px, float), (len(U),))
    return np.sqrt(np.einsum("nii->ni", U)) * sig[:, None]
