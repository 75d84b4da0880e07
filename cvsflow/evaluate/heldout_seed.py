"""The chapter's method scored on held-out time blocks (rule ``heldout_seed``).

``cross_validate_seed`` fits f and P̄ (eqs. 1.10-1.12) on all folds of
:func:`cvsflow.evaluate.heldout.make_time_blocks` but one and scores the held-out fold at that f
(eq. 1.11), every fold; :func:`cvsflow.evaluate.heldout.compare_heldout` compares it with se3's.
"""

from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from cvsflow.evaluate.heldout import make_time_blocks
from cvsflow.exceptions import WholeBoardError
from cvsflow.metrics import ERROR_DIMS
from cvsflow.optimise import MIN_PAIRS, SE3_ALONE, SeedPoseCache, compute_eps, optimise_seed

log = logging.getLogger(__name__)


def cross_validate_seed(pairs, corners, K, dist, board, *, n_folds=5, block_s=5.0, seed=0,
                        folds=None, progress=None, **seed_options):
    """Fit the chapter's method on all folds but one, score the held-out fold; every fold.

    The fit gives f and P̄ (eqs. 1.10-1.12) from the training frames only; the held-out
    frames' poses are re-estimated at that f and their error is eq. 1.11 with the training P̄.
    The folds' fits share the PnP solves they have in common (all of the first iteration's:
    every fold starts from the same f and poses) through one
    :class:`cvsflow.optimise.seed_cache.SeedPoseCache`; the result is the one of fitting each
    fold on its own, bit for bit.

    Parameters
    ----------
    pairs, corners : DataFrame
        pairs.parquet and corners.parquet.
    K, dist : array_like
        Calibrated intrinsics (the seed method's start).
    board : dict
    n_folds, block_s, seed
        As :func:`make_time_blocks`, used when ``folds`` is not given.
    folds : DataFrame, optional
        ``t_s`` and ``fold`` of other frames (:func:`cvsflow.evaluate.heldout.heldout_blocks`, the
        blocks :func:`cvsflow.evaluate.heldout.cross_validate_se3` uses): each pair frame takes the fold
        of the nearest of those frames in time, so that both methods are scored on the same
        held-out blocks.
    progress : callable, optional
        ``progress(k)`` as each fold starts and at the end, k folds done.
    **seed_options
        Passed to :func:`cvsflow.optimise.seed.optimise_seed`.

    Returns
    -------
    heldout : DataFrame
        ``frame, t_s, fold, fx_px, fy_px``, ``eps_{dim}`` (6-vector errors, m and rad), and
        ``diverged``, ``diverged_reason`` of the fold's fit (:func:`optimise_seed`). A fold
        whose training or held-out frames hold fewer than ``MIN_PAIRS`` pairs, or whole boards
        (a hand over the board for a while), is left out with a WARNING, its frames unscored.

    Raises
    ------
    WholeBoardError
        No fold could be fitted and scored.
    """
    t_s = pairs["t_s"].to_numpy(float)
    if folds is None:
        fold = make_time_blocks(t_s, block_s, n_folds, seed)
    else:
        order = np.argsort(folds["t_s"].to_numpy(float))
        t_other = folds["t_s"].to_numpy(float)[order]
        f_other = folds["fold"].to_numpy(int)[order]
        i = np.clip(np.searchsorted(t_other, t_s), 1, len(t_other) - 1)
        nearer_left = np.abs(t_s - t_other[i - 1]) <= np.abs(t_other[i] - t_s)
        fold = np.where(nearer_left, f_other[i - 1], f_other[i])
        n_folds = int(f_other.max()) + 1
    dims = list(ERROR_DIMS)
    parts = []
    cache = SeedPoseCache(pairs, corners, board)
    seed_options = {**seed_options, "pose_cache": cache}
    left_out = []
    for k in range(n_folds):
        if progress:
            progress(k)
        train, test = pairs[fold != k], pairs[fold == k]
        if len(test) == 0:
            continue
        if min(len(train), len(test)) < MIN_PAIRS:
            # a fold whose block held few poses (the board lost for a while): too few to fit
            # or score by the chapter's method, as when a hand hides it
            why = (f"{len(train)} training and {len(test)} held-out pairs; the seed method "
                   f"needs at least {MIN_PAIRS} of each")
            log.warning("seed cross-validation fold %d left out: %s", k, why)
            left_out.append(f"fold {k}: {why}")
            continue
        try:
            fit = optimise_seed(train, corners, K, dist, board, **seed_options)
            f = (fit.result["fx_px"], fit.result["fy_px"])
            opts = {**seed_options, "k_iterations": 0, "f_init_px": f}
            scored = optimise_seed(test, corners, K, dist, board, **opts).errors
        except WholeBoardError as exc:
            # a hand over the board for a block of the take: this fold cannot be fitted or
            # scored by a method that needs the whole board; the others still can
            log.warning("seed cross-validation fold %d left out (%d test frames): %s",
                        k, len(test), exc)
            # the advice once, at the end of the error, not once per fold
            left_out.append(f"fold {k}: {str(exc).replace(SE3_ALONE, '').strip()}")
            continue
        F = scored[[f"cvs_{d}" for d in dims]].to_numpy(float)
        P_star = scored[[f"vic_{d}" for d in dims]].to_numpy(float)
        eps = compute_eps(F, P_star, np.asarray(fit.result["P_bar"], float))  # eq. 1.11
        part = pd.DataFrame({"frame": scored["frame"].to_numpy(), "t_s": scored["t_s"].to_numpy()})
        part["fold"], part["fx_px"], part["fy_px"] = k, f[0], f[1]
        part["diverged"] = bool(fit.result.get("diverged", False))
        part["diverged_reason"] = fit.result.get("diverged_reason") or ""
        for j, d in enumerate(dims):
            part[f"eps_{d}"] = eps[:, j]
        parts.append(part)
        log.info("seed cross-validation fold %d: %d train, %d test frames, f = (%.1f, %.1f) px",
                 k, len(train), len(test), *f)
    if progress:
        progress(n_folds)
    log.info("seed cross-validation: %d (candidate, frame) PnP rows solved, %d shared by folds",
             cache.n_solved, cache.n_reused)
    if not parts:
        raise WholeBoardError("seed cross-validation: no fold could be fitted and scored; "
                              + "; ".join(left_out) + f". {SE3_ALONE}")
    return pd.concat(parts, ignore_index=True).sort_values("frame", ignore_index=True)
