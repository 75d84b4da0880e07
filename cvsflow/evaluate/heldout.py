"""Held-out time blocks over the composed SE(3) errors of :mod:`cvsflow.metrics`, and the comparison.

- :func:`make_time_blocks`, :func:`heldout_blocks` and :func:`cross_validate_se3`: fit on some
  contiguous time blocks, score on the others; the held-out figures are the ones to state.
- :func:`compare_methods`, :func:`compare_heldout`: the methods' held-out statistics
  (:func:`cvsflow.metrics.axis_statistics`) side by side, with moving-block bootstrap intervals
  (:func:`cvsflow.metrics.bootstrap_error_stats`).

Errors are ``estimate - reference``: the CVS pose (PnP) against the Vicon reference.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow import geometry as geo
from cvsflow import uncertainty as un
from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.metrics import (
    ERROR_DIMS,
    axis_statistics,
    bootstrap_error_stats,
    error_columns,
    frame_errors,
    poses_from_table,
)
from cvsflow.optimise import DIVERGED_EPS_STD_M, Se3Share, apply_se3, corner_arrays, optimise_se3

log = logging.getLogger(__name__)

def make_time_blocks(t_s, block_s, n_folds, seed):
    """Assign frames to folds by contiguous time blocks, the blocks shuffled by a seed.

    Parameters
    ----------
    t_s : array_like, shape (N,)
        Frame times, s.
    block_s : float
        Block length, s (longer than the errors' correlation time: a few seconds).
    n_folds : int
        Number of folds (>= 2).
    seed : int
        Seed of the shuffle of blocks to folds.

    Returns
    -------
    fold : ndarray of int, shape (N,)
        Fold of every frame, 0..n_folds-1; each fold gets whole blocks, in near-equal numbers.
        A last block shorter than ``block_s / 2`` is part of the one before it.

    Raises
    ------
    OptimiseError
        Fewer blocks than folds, n_folds < 2 or block_s <= 0.
    """
    t = np.asarray(t_s, float)
    if n_folds < 2 or not block_s > 0:
        raise OptimiseError(
            f"make_time_blocks: n_folds={n_folds}, block_s={block_s}; expected >= 2 and > 0 s"
        )
    block = np.floor((t - t.min()) / block_s).astype(int)
    # A tail shorter than half a block joins the block before it: alone it would make a fold
    # of a few frames (a 10.07 s take in 2 s blocks gave one fold 3 frames, another 118).
    last = block.max()
    if last > 0 and t.max() - t.min() - last * block_s < 0.5 * block_s:
        block[block == last] = last - 1
    blocks = np.unique(block)
    if len(blocks) < n_folds:
        raise OptimiseError(
            f"make_time_blocks: {len(blocks)} blocks of {block_s} s in {np.ptp(t):.1f} s, "
            f"fewer than {n_folds} folds; a longer recording, or fewer folds "
            f"(evaluate.n_folds) or shorter blocks (evaluate.block_s, not under the errors' "
            f"correlation time of about a second)"
        )
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(blocks))
    fold_of_block = np.empty(len(blocks), int)
    fold_of_block[order] = np.arange(len(blocks)) % n_folds
    return fold_of_block[np.searchsorted(blocks, block)]


def heldout_blocks(corners, board, *, n_folds=5, block_s=5.0, seed=0):
    """The held-out fold of every frame with corners: the blocks all methods are scored on.

    :func:`cross_validate_se3` fits and scores on these folds, and the seed method's held-out
    scoring (:func:`cvsflow.evaluate.heldout_seed.cross_validate_seed`) takes them from the same
    corners table, so that it need not wait for se3's held-out scoring to know them.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet.
    board : dict
    n_folds, block_s, seed
        As :func:`make_time_blocks`.

    Returns
    -------
    DataFrame
        ``frame, t_s, fold``: each frame kept by
        :func:`cvsflow.optimise.se3_start.corner_arrays`, its video time (s) and fold.
    """
    frame_ids, t_video, _ = corner_arrays(corners, len(board_object_points(board)))
    fold = make_time_blocks(t_video, block_s, n_folds, seed)
    return pd.DataFrame({"frame": frame_ids, "t_s": t_video, "fold": fold})


def cross_validate_se3(
    corners, bodies, camera, board, dt_offset_s, *, n_folds=5, block_s=5.0, seed=0,
    frame="C", progress=None, **se3_options,
):  # fmt: skip
    """Fit se3 on all folds but one, score the held-out fold; every fold in turn.

    The folds share the corner arrays, the body tracks and every frame's PnP pose at a camera
    (:class:`cvsflow.optimise.se3_share.Se3Share`): each fold's fit is the one it had alone.

    Parameters
    ----------
    corners, bodies, camera, board, dt_offset_s
        As :func:`cvsflow.optimise.se3.optimise_se3`.
    n_folds : int
        Folds of contiguous time blocks.
    block_s : float
        Block length, s.
    seed : int
        Seed of the block-to-fold assignment.
    frame : {"C", "B"}
        Frame of the errors (:func:`pose_errors`).
    progress : callable, optional
        ``progress(k)`` after each fold, k folds done.
    **se3_options
        Passed to ``optimise_se3`` (free, loss, f_scale_px, ...).

    Returns
    -------
    heldout : DataFrame
        One row per frame, scored by the fit that did not see it: the :func:`frame_errors`
        columns plus ``fold``; ``sigma_px`` of that fit.
    fits : list of dict
        ``result`` of each fold's fit, with ``fold`` added.
    """
    blocks = heldout_blocks(corners, board, n_folds=n_folds, block_s=block_s, seed=seed)
    frame_ids, fold = blocks["frame"].to_numpy(), blocks["fold"].to_numpy()
    parts, fits = [], []
    share = Se3Share(corners, bodies, board)  # what the folds' fits have in common, made once
    for k in range(n_folds):
        train = frame_ids[fold != k]
        test = frame_ids[fold == k]
        fit = optimise_se3(corners, bodies, camera, board, dt_offset_s, frames=train, share=share,
                           per_frame=False, **se3_options)
        res = dict(fit.result)
        res["fold"] = k
        fits.append(res)
        scored = frame_errors(apply_se3(res, corners, bodies, board, frames=test, share=share),
                              frame=frame)
        scored["fold"] = k
        scored["sigma_px"] = res["sigma_px"]
        parts.append(scored)
        log.info("cross-validation fold %d: %d train, %d test frames", k, len(train), len(test))
        if progress:
            progress(k + 1)
    heldout = pd.concat(parts, ignore_index=True).sort_values("frame", ignore_index=True)
    return heldout, fits


# ---------------------------------------------------------------------------------------------
# Tables the workflow hands to the analysis, and the side-by-side comparison of methods


def _pose6_block(frames, prefix):
    """(N, 6) pose6 [x, y, z, roll, pitch, yaw] of the ``prefix`` pose columns (m, rad)."""
    return geo.pose6_from_T(poses_from_table(frames, prefix))


def se3_run_tables(fit, corners, bodies, board, poses_raw, frame="C", share=None):
    """The se3 run in the analysis' form: per-iteration table, per-frame errors, result.

    Parameters
    ----------
    fit : OptimiseResult
        :func:`cvsflow.optimise.se3.optimise_se3` output.
    corners, bodies : DataFrame
        corners.parquet and the native-rate bodies.parquet.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    poses_raw : DataFrame
        poses_raw.parquet: the PnP poses at the calibrated intrinsics ("original" CVS).
    frame : {"C", "B"}
        Frame of the composed errors.
    share : cvsflow.optimise.se3_share.Se3Share, optional
        The one ``fit`` was made with: its tracks and PnP poses are reused.

    Returns
    -------
    iterations : DataFrame
        The solver's steps: ``iteration``, ``cost``, ``rms_px``, ``fx_px``, ``fy_px``,
        ``dt_offset_s``.
    errors : DataFrame
        Per frame: ``frame, t_s``; ``eps_{dim}`` the composed error (estimate - Vicon
        reference, :func:`pose_errors`), ``d6_{dim}`` the chapter's 6-vector difference,
        ``err_angle_rad``, ``err_dist_m``; ``vic_{dim}`` (reference T_C_B from the Vicon),
        ``cvs_{dim}`` (PnP at the fitted intrinsics), ``cvs_orig_{dim}`` (poses_raw).
    result : dict
        ``fit.result`` plus ``fx_px``, ``fy_px``, ``f_init_px``, ``n_pairs``, the error frame
        and the RMS translation error at the start and at the optimum
        (``norm_normalised_init_m``, ``norm_normalised_final_m``).
    """
    result = dict(fit.result)
    final = frame_errors(apply_se3(result, corners, bodies, board, share=share), frame=frame)
    errors = pd.DataFrame({"frame": final["frame"].to_numpy(), "t_s": final["t_s"].to_numpy()})
    vic, cvs = _pose6_block(final, "ref_"), _pose6_block(final, "cvs_")
    orig = poses_raw.set_index("frame").reindex(final["frame"].to_numpy())
    for j, d in enumerate(ERROR_DIMS):
        errors[f"eps_{d}"] = final[f"err_{d}"].to_numpy()
        errors[f"d6_{d}"] = final[f"d6_{d}"].to_numpy()
        errors[f"vic_{d}"] = vic[:, j]
        errors[f"cvs_{d}"] = cvs[:, j]
        errors[f"cvs_orig_{d}"] = orig[d].to_numpy(float)
    errors["err_angle_rad"] = final["err_angle_rad"].to_numpy()
    errors["err_dist_m"] = final["err_dist_m"].to_numpy()

    init = result.get("init")
    norm_init = np.nan
    if isinstance(init, dict) and {"K", "dist", "T_Cm_C", "T_Bm_B", "dt_offset_s"} <= set(init):
        start = frame_errors(apply_se3({**result, **init}, corners, bodies, board, share=share),
                             frame=frame)
        norm_init = float(np.sqrt(np.mean(start["err_dist_m"] ** 2)))
    K = np.asarray(result["K"], float)
    K0 = np.asarray(init["K"], float) if isinstance(init, dict) and "K" in init else K
    result.update(
        fx_px=float(K[0, 0]), fy_px=float(K[1, 1]), f_init_px=[float(K0[0, 0]), float(K0[1, 1])],
        n_pairs=int(len(errors)), error_frame=frame,
        norm_normalised_init_m=norm_init,
        norm_normalised_final_m=float(np.sqrt(np.mean(final["err_dist_m"] ** 2))),
    )
    iterations = fit.iterations.reset_index(drop=True).copy()
    iterations.insert(0, "iteration", np.arange(len(iterations)))
    return iterations, errors, result


def crossfit_error_model(heldout, features, cov_err=None):
    """Train the error model on the held-out errors of all folds but one, score the last.

    Every error used is out of sample for the calibration (cross-validated); the model is
    then also scored on frames it was not trained on. Pooled over the folds.

    Parameters
    ----------
    heldout : DataFrame
        :func:`cross_validate_se3` output (``fold``, ``err_{dim}``, ``t_s``).
    features : DataFrame
        :func:`cvsflow.uncertainty.error_features` of the same rows; when made with the
        folds' fits (``fits=``) the model is (P) (the scored fit's parameter covariance,
        scaled, plus a floor; its full covariance is used in the NEES), else (M).
    cov_err : ndarray, shape (N, 6, 6), optional
        The propagated PnP error covariance of the same rows (per-frame correlation of the
        NEES of model (M)).

    Returns
    -------
    score : dict
        ``n``, ``inside_68``, ``inside_95`` (per dimension and ``_all`` pooled), ``nees_mean``,
        ``nees_inside_95``, ``folds`` (per-fold scores), ``model`` (``P`` or ``M``).
    sigma : ndarray, shape (N, 6)
        Predicted standard deviation of every row, by the model that did not see its fold.
    mu : ndarray, shape (N, 6)
        Predicted bias of every row.
    """
    fold = heldout["fold"].to_numpy()
    sigma = np.full((len(heldout), 6), np.nan)
    mu = np.full((len(heldout), 6), np.nan)
    folds = []
    for k in np.unique(fold):
        train, test = fold != k, fold == k
        model = un.fit_error_model(features[train].reset_index(drop=True),
                                heldout[train].reset_index(drop=True))
        f_test = features[test].reset_index(drop=True)
        sigma[test], mu[test] = un.predict_error_sigma(model, f_test)
        s = un.score_error_model(model, f_test, heldout[test].reset_index(drop=True),
                              None if cov_err is None else cov_err[test])
        s["fold"] = int(k)
        folds.append(s)
    n = np.array([s["n"] for s in folds], float)
    w = n / n.sum()
    out = {"n": int(n.sum()), "folds": folds, "model": model.get("kind", "M")}

    def pooled(get):
        return float(sum(wi * get(s) for wi, s in zip(w, folds, strict=True)))

    for band in ("68", "95"):
        out[f"inside_{band}"] = {d: pooled(lambda s, b=band, d=d: s[f"inside_{b}"][d]) for d in ERROR_DIMS}
        out[f"inside_{band}_all"] = pooled(lambda s, b=band: s[f"inside_{b}_all"])
    out["nees_mean"] = pooled(lambda s: s["nees_mean"])
    out["nees_inside_95"] = pooled(lambda s: s["nees_inside_95"])
    return out, sigma, mu


def compare_methods(heldout_by_method, *, block_len=30, n_boot=1000, seed=0, level=0.95):
    """Held-out error statistics of each method side by side, with block-bootstrap intervals.

    Parameters
    ----------
    heldout_by_method : dict
        Method name -> held-out table with ``eps_{dim}`` (se3: composed errors; seed: the
        chapter's 6-vector errors), in time order.
    block_len : int
        Bootstrap block length in frames.

    Returns
    -------
    dict
        Per method: ``n`` and per dimension the statistics of
        :data:`cvsflow.metrics.STATISTICS` (SI) with ``mean_lo``, ``mean_hi``, ``std_lo``,
        ``std_hi`` (block-bootstrap intervals); and, when both ``seed`` and ``se3`` are given,
        ``rmse_ratio_se3_to_seed`` per dimension.
    """
    out = {}
    for method, table in heldout_by_method.items():
        E = table[error_columns("eps")].to_numpy(float)
        finite = np.isfinite(E).all(axis=1)
        if finite.sum() < 3:
            raise OptimiseError(f"compare_methods: {method} has {int(finite.sum())} held-out frames "
                                "with finite errors; at least 3 are needed")
        if not finite.all():
            log.warning("compare_methods: %s: %d of %d held-out frames without a finite error left out",
                        method, int((~finite).sum()), len(E))
            E = E[finite]
        boot = bootstrap_error_stats(E, min(block_len, len(E)), n_boot=n_boot, seed=seed, level=level)
        per_dim = axis_statistics(E)
        for j, d in enumerate(ERROR_DIMS):
            for name in ("mean", "std"):
                per_dim[d][f"{name}_lo"] = float(boot[f"{name}_lo"][j])
                per_dim[d][f"{name}_hi"] = float(boot[f"{name}_hi"][j])
        out[method] = {"n": int(len(E)), "per_dim": per_dim}
    if {"seed", "se3"} <= set(out):
        out["rmse_ratio_se3_to_seed"] = {
            d: out["se3"]["per_dim"][d]["rmse"] / out["seed"]["per_dim"][d]["rmse"] for d in ERROR_DIMS
        }
    return out


def compare_heldout(seed_heldout, se3_heldout, se3_result, fold_fits, board, *, frame="C",
                    boot_block_s=2.0, n_boot=1000, seed=0, corners=None, transfer_model=None,
                    bodies=None, inter_coded=False):
    """The comparison stage: both methods' held-out statistics and the error model's calibration.

    Parameters
    ----------
    seed_heldout : DataFrame or None
        :func:`cvsflow.evaluate.heldout_seed.cross_validate_seed` output (``eps_*``, 6-vector errors);
        None for a session that runs se3 alone: the comparison then has no ``seed`` section
        and no ``rmse_ratio_se3_to_seed``, and the error model is scored as with both.
    se3_heldout : DataFrame
        :func:`cross_validate_se3` output (``err_*`` composed errors, ``fold``, ``sigma_px``).
    se3_result : dict
        The full se3 fit (``K``, ``dist``): the linearisation of the per-frame PnP covariance.
    fold_fits : list of dict
        Each fold's se3 result: its parameter covariance is shared by every frame it scores,
        and dominates the PnP corner noise in the error model.
    board : dict
    frame : {"C", "B"}
        Frame of the composed errors.
    boot_block_s, n_boot, seed
        Moving-block bootstrap: block length (s), resamples and seed.
    corners : DataFrame, optional
        corners.parquet of the session: with it the error model is (T)
        (:func:`cvsflow.uncertainty.crossfit_transfer`, what each frame's measurement tells:
        its seen corners, speed, reprojection RMS, the fold fit's calibration covariance and
        line delay), and the Cramer-Rao floor is reported; without, the older model (P).
    bodies : DataFrame, optional
        bodies.parquet: which frames' board markers were gap-filled (``vicon_filled``).
    transfer_model : dict, optional
        A model (T) fitted on other sessions (default
        :data:`cvsflow.uncertainty.RENDERED_TRANSFER_MODEL`), scored here as
        ``error_model_transfer`` (with ``corners``).
    inter_coded : bool
        The video is motion-compensated (corners_summary.yaml ``inter_coded``): model (T)
        gets its still-board codec term (:func:`cvsflow.uncertainty.measurement_features`).

    Returns
    -------
    comparison : dict
        :func:`compare_methods` output plus ``error_model`` (the within-session cross-fit
        score, per fold in ``folds[]``: ``nees_mean``, ``inside_68``, ``inside_95`` per axis,
        ...), ``error_frame``; with ``corners`` also ``error_model_fit`` (model (T) fitted on
        all the session's frames, :func:`cvsflow.uncertainty.fit_transfer_model`'s dict: the
        model a flight measured with this camera states its reference with),
        ``error_model_transfer`` (the model fitted on other sessions, same keys as
        ``error_model``) and ``cramer_rao`` (``error_over_crb``: RMS of held-out error / CRB
        per axis; ``crb_median`` per axis, SI; ``sigma_px``).
    se3_errors : DataFrame
        The se3 held-out table with ``eps_*`` equal to its composed errors; with ``corners``
        also ``sigma_{dim}`` (predicted), ``mu_{dim}`` (predicted error), ``crb_{dim}``
        (Cramer-Rao standard deviation) and ``nees``.
    sigma, mu : ndarray, shape (N, 6)
        Predicted standard deviation and bias of every se3 held-out frame.
    """
    se3 = se3_heldout.copy()
    se3["t_s"] = se3["t_s"].astype(float)
    for d in ERROR_DIMS:
        se3[f"eps_{d}"] = se3[f"err_{d}"]
    fps = 1.0 / geo.sample_period(se3["t_s"])
    by_method = {"se3": se3} if seed_heldout is None else {"seed": seed_heldout, "se3": se3}
    comparison = compare_methods(by_method,
                                 block_len=max(1, int(round(boot_block_s * fps))),
                                 n_boot=n_boot, seed=seed)
    if corners is not None:
        feats = un.measurement_features(se3, corners, board, fits=fold_fits, frame=frame,
                                        bodies=bodies, inter_coded=inter_coded)
        # the session's own model (T) on all its frames: what its flights state their
        # reference's uncertainty with (the camera-side terms; the floors are its Vicon's);
        # the folds' fits start from it
        session_fit = un.fit_transfer_model(feats, se3)
        score, cov, mu = un.crossfit_transfer(feats, se3, start=session_fit)
        comparison["error_model"] = score
        comparison["error_model_fit"] = session_fit
        model = un.RENDERED_TRANSFER_MODEL if transfer_model is None else transfer_model
        sig_px = se3["sigma_px"].to_numpy(float)
        tr = un.score_transfer(model, feats, se3, se3["fold"].to_numpy(), sig_px)
        comparison["error_model_transfer"] = {k: v for k, v in tr.items()
                                              if k not in ("error_over_crb", "crb_median")}
        comparison["error_model_transfer"]["params"] = {n: model[n] for n in un.TRANSFER_PARAMS}
        comparison["cramer_rao"] = {"error_over_crb": tr["error_over_crb"],
                                    "crb_median": tr["crb_median"],
                                    "sigma_px": float(np.median(sig_px))}  # fmt: skip
        sigma = np.sqrt(np.einsum("nii->ni", cov))
        crb = un.cramer_rao_sigma(feats, sig_px)
        for j, d in enumerate(ERROR_DIMS):
            se3[f"sigma_{d}"] = sigma[:, j]
            se3[f"mu_{d}"] = mu[:, j]
            se3[f"crb_{d}"] = crb[:, j]
        se3["nees"] = un.nees_values(cov, se3, mean=mu)
        comparison["error_frame"] = frame
        if seed_heldout is not None:
            mark_seed_divergence(comparison, seed_heldout)
        return comparison, se3, sigma, mu
    features, cov_err = un.error_features(
        se3, board_object_points(board), np.asarray(se3_result["K"], float),
        np.asarray(se3_result["dist"], float), float(np.median(se3["sigma_px"])), frame=frame,
        fits=fold_fits,
    )  # fmt: skip
    score, sigma, mu = crossfit_error_model(se3, features, cov_err)
    comparison["error_model"] = score
    comparison["error_frame"] = frame
    if seed_heldout is not None:
        mark_seed_divergence(comparison, seed_heldout)
    return comparison, se3, sigma, mu


def mark_seed_divergence(comparison, seed_heldout):
    """Move a diverged seed's statistics under a key that says they are not measurements.

    The seed section becomes ``{diverged: true, diverged_reason, n,
    statistics_not_measurements: {per_dim}}`` and ``rmse_ratio_se3_to_seed`` moves to
    ``rmse_ratio_se3_to_seed_not_measurements`` (the top-level key is None), when any fold's fit
    diverged (``diverged`` column of :func:`cvsflow.evaluate.heldout_seed.cross_validate_seed`) or a
    held-out translation error std exceeds ``cvsflow.optimise.seed.DIVERGED_EPS_STD_M``.
    Otherwise the section gets ``diverged: false``.

    Parameters
    ----------
    comparison : dict
        :func:`compare_methods` output with a ``seed`` section (edited in place).
    seed_heldout : DataFrame
        :func:`cvsflow.evaluate.heldout_seed.cross_validate_seed` output (``fold``, ``diverged``,
        ``diverged_reason``).

    Returns
    -------
    comparison : dict
        The same mapping.
    """
    sec = comparison["seed"]
    reasons = []
    if "diverged" in seed_heldout and seed_heldout["diverged"].astype(bool).any():
        bad = seed_heldout[seed_heldout["diverged"].astype(bool)]
        for k, g in bad.groupby("fold"):
            reasons.append(f"fold {int(k)}: {g['diverged_reason'].iloc[0]}")
    for d in ("x_m", "y_m", "z_m"):
        std = sec["per_dim"][d]["std"]
        if not std <= DIVERGED_EPS_STD_M:
            reasons.append(f"held-out {d} std {std:.3f} m exceeds {DIVERGED_EPS_STD_M:g} m")
    if not reasons:
        sec["diverged"] = False
        return comparison
    log.warning("seed diverged (%s); its held-out statistics are not measurements", "; ".join(reasons))
    comparison["seed"] = {
        "diverged": True,
        "diverged_reason": "; ".join(reasons),
        "n": sec["n"],
        "statistics_not_measurements": {"per_dim": sec["per_dim"]},
    }
    comparison["rmse_ratio_se3_to_seed_not_measurements"] = comparison.get("rmse_ratio_se3_to_seed")
    comparison["rmse_ratio_se3_to_seed"] = None
    return comparison
