"""Focal-length and offset optimisers: ``seed`` (the chapter, eqs. 1.5-1.12) and ``se3`` (the joint
SE(3) fit), each returning an :class:`OptimiseResult`."""

from cvsflow.optimise.body_tracks import CAMERA_MOVING_SMOOTH_S, BodyTrack, smooth_track_local
from cvsflow.optimise.result import OptimiseResult
from cvsflow.optimise.se3 import MIN_FRAMES, camera_start, keep_usable, optimise_se3, usable_frames
from cvsflow.optimise.se3_apply import apply_se3, pose_columns, tracks_from_params
from cvsflow.optimise.se3_cov import (
    DEFAULT_INTRINSIC_STD,
    covariances,
    fixed_intrinsic_std,
    parameter_covariance,
)
from cvsflow.optimise.se3_fit import (
    DEFAULT_FREE,
    Se3Options,
    correlation_warnings,
    fixed_std,
    solve,
    uncertainty_keys,
)
from cvsflow.optimise.se3_lm import LOSSES, levenberg_marquardt, refuse_implausible_fit, robust_cost
from cvsflow.optimise.se3_model import K_from_intrinsics, Se3Model, jacobian_fd
from cvsflow.optimise.se3_share import Se3Share
from cvsflow.optimise.se3_sim import simulate_rig_session, simulate_session
from cvsflow.optimise.se3_start import corner_arrays, solve_hand_eye, solve_pnp_frames
from cvsflow.optimise.seed import DIVERGED_EPS_STD_M, compute_eps, compute_p_bar, optimise_seed
from cvsflow.optimise.seed_cache import SeedPoseCache
from cvsflow.optimise.seed_search import MIN_PAIRS, SE3_ALONE, SeedOptions

__all__ = [
    "apply_se3", "BodyTrack", "CAMERA_MOVING_SMOOTH_S", "camera_start", "compute_eps",
    "compute_p_bar", "corner_arrays", "correlation_warnings", "covariances", "DEFAULT_FREE",
    "DEFAULT_INTRINSIC_STD", "DIVERGED_EPS_STD_M", "fixed_intrinsic_std", "fixed_std",
    "jacobian_fd", "K_from_intrinsics", "keep_usable", "levenberg_marquardt", "LOSSES",
    "MIN_FRAMES", "MIN_PAIRS", "optimise_se3", "optimise_seed", "OptimiseResult",
    "parameter_covariance", "pose_columns", "refuse_implausible_fit", "robust_cost", "SE3_ALONE",
    "Se3Model", "Se3Options", "Se3Share", "SeedOptions", "SeedPoseCache", "simulate_rig_session",
    "simulate_session", "smooth_track_local", "solve", "solve_hand_eye", "solve_pnp_frames",
    "tracks_from_params", "uncertainty_keys", "usable_frames"
]
