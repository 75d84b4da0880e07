"""Per-frame pose error covariance: propagated, modelled, scored.

- :mod:`cvsflow.uncertainty.propagation`: the PnP pose covariance under iid corner noise
  (:func:`pnp_covariance`), pushed to the composed error (:func:`propagated_pose_covariance`)
  or the pose 6-vector (:func:`pose6_covariance`), and the covariance each held-out frame
  inherits from the se3 fit that scored it (:func:`parameter_covariance`).
- :mod:`cvsflow.uncertainty.models`: the one-session error models (M) and (P)
  (:func:`fit_error_model`, :func:`predicted_covariance`, :func:`score_error_model`).
- :mod:`cvsflow.uncertainty.features`: what is known of a frame when it is measured
  (:func:`measurement_features`, the corner noise its reprojection implies).
- :mod:`cvsflow.uncertainty.transfer`: model (T), fitted on some sessions, predicting
  another or a flight (:func:`fit_transfer_model`, :func:`transfer_covariance`,
  :data:`RENDERED_TRANSFER_MODEL`); :mod:`cvsflow.uncertainty.transfer_scoring` scores it on
  frames it did not see (:func:`score_transfer`, :func:`leave_one_session_out`,
  :func:`crossfit_transfer`, :func:`transfer_nll`).
- :mod:`cvsflow.uncertainty.scoring`: band coverage and NEES (:func:`score_covariance`,
  :func:`nees_values`, :func:`band_multipliers`), and the same with the errors whitened by
  an AR(1) in time (:func:`fit_ar1`, :func:`score_time_correlated`).
- :mod:`cvsflow.uncertainty.calibrated_draws`: how many of the coverage targets a model that
  is exactly right meets on short, time-correlated held-out sets (:func:`target_pass_rates`;
  the draws themselves: :func:`draw_calibrated_errors`).
- :mod:`cvsflow.uncertainty.crb`: the Cramer-Rao floor (:func:`cramer_rao_sigma`).
- :mod:`cvsflow.uncertainty.rolling_shutter`: a rolling shutter's shear of the corners and
  the pose without it (:func:`shear_displacement`, :func:`unsheared_pnp`).
- :mod:`cvsflow.uncertainty.ambiguity`: the planar PnP's second solution
  (:func:`pnp_alternatives`) and the chance it is the true pose (:func:`flip_weight`).

The submodules import each other downwards (ambiguity, propagation, scoring, rolling_shutter <
calibrated_draws, models, features, crb < transfer < transfer_scoring); this package only
re-exports their public names.
"""

from cvsflow.uncertainty.ambiguity import flip_weight, pnp_alternatives
from cvsflow.uncertainty.calibrated_draws import (
    TARGETS,
    autocorrelation,
    draw_calibrated_errors,
    excess_spread,
    session_scale_sd,
    target_pass_rates,
)
from cvsflow.uncertainty.crb import cramer_rao_sigma
from cvsflow.uncertainty.features import (
    CORNER_CORRELATION_PX,
    FILL_WINDOW_S,
    MEASUREMENT_FEATURES,
    NOISE_POOL_COLUMN,
    corner_noise_from_reproj,
    corner_noise_pool,
    correlated_noise_terms,
    frame_noise_terms,
    measurement_features,
    seen_corners,
    shrink_corner_noise,
    still_board_weight,
    vicon_filled,
)
from cvsflow.uncertainty.models import (
    FEATURES,
    error_features,
    fit_error_model,
    predict_error_sigma,
    predicted_covariance,
    score_error_model,
)
from cvsflow.uncertainty.propagation import (
    PARAM_BLOCKS,
    composed_error_jacobian,
    cov_columns,
    cov_from_columns,
    parameter_covariance,
    pnp_covariance,
    pose6_covariance,
    propagated_pose_covariance,
)
from cvsflow.uncertainty.rolling_shutter import shear_displacement, unsheared_pnp
from cvsflow.uncertainty.scoring import (
    BANDS,
    WORKING_UNITS,
    ar1_innovations,
    band_multipliers,
    block_mean_variance,
    chi2_pdf,
    chi2_quantile,
    fit_ar1,
    fit_multivariate_t,
    frame_runs,
    nees_values,
    score_covariance,
    score_time_correlated,
    standardised_errors,
)
from cvsflow.uncertainty.transfer import (
    RENDERED_TRANSFER_MODEL,
    TRANSFER_PARAMS,
    fit_transfer_model,
    transfer_covariance,
    transfer_mean,
)
from cvsflow.uncertainty.transfer_scoring import (
    crossfit_transfer,
    leave_one_session_out,
    score_transfer,
    time_correlation_of,
    transfer_nll,
)

__all__ = [
    "ar1_innovations", "autocorrelation", "band_multipliers", "BANDS", "block_mean_variance",
    "chi2_pdf", "chi2_quantile", "composed_error_jacobian", "CORNER_CORRELATION_PX",
    "corner_noise_from_reproj", "corner_noise_pool", "correlated_noise_terms", "cov_columns",
    "cov_from_columns", "cramer_rao_sigma", "crossfit_transfer", "error_features", "excess_spread",
    "draw_calibrated_errors",
    "FEATURES", "FILL_WINDOW_S", "fit_ar1", "fit_multivariate_t", "fit_error_model", "fit_transfer_model",
    "flip_weight",
    "frame_noise_terms", "frame_runs", "leave_one_session_out", "measurement_features",
    "MEASUREMENT_FEATURES", "nees_values", "NOISE_POOL_COLUMN", "PARAM_BLOCKS", "parameter_covariance",
    "pnp_alternatives", "pnp_covariance", "pose6_covariance", "predict_error_sigma",
    "predicted_covariance", "propagated_pose_covariance", "RENDERED_TRANSFER_MODEL", "score_covariance",
    "score_error_model", "score_time_correlated", "score_transfer", "seen_corners", "session_scale_sd",
    "shear_displacement", "shrink_corner_noise", "standardised_errors", "still_board_weight",
    "target_pass_rates", "TARGETS", "time_correlation_of", "transfer_covariance", "transfer_mean",
    "transfer_nll", "TRANSFER_PARAMS", "unsheared_pnp", "vicon_filled", "WORKING_UNITS"
]
