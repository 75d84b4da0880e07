"""The seed method's settings, its checked inputs and its grid search of the focal lengths
(step c, eq. 1.12), the parts :func:`cvsflow.optimise.seed.optimise_seed` iterates.

Every candidate (fx, fy) re-runs PnP on all frames: the candidates of one grid level are one
stack of (candidate, frame) rows (:func:`cvsflow.optimise.seed_pnp.solve_rows`), warm-started
from the poses at the current focal lengths moved by their first-order sensitivity to (fx, fy).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import pandas as pd

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError, WholeBoardError
from cvsflow.geometry import R_from_rvec
from cvsflow.metrics import ERROR_DIMS
from cvsflow.optimise.result import build_options
from cvsflow.optimise.seed_pnp import dist5, focal_sensitivity, solve_rows

log = logging.getLogger(__name__)

#: The objectives of step c) (eq. 1.12 and its variants; :mod:`cvsflow.optimise.seed`).
OBJECTIVES = ("summed", "sum_abs", "sum_squares")
#: Fewest pairs the optimiser accepts (6 unknowns of P_bar, 2 focal lengths).
MIN_PAIRS = 10
#: The way out when too few frames show the whole board.
SE3_ALONE = ("se3 uses partly hidden boards: run it alone, for this session with methods: [se3] "
             "in its sessions.<name> block (or for all with optimise.methods: [se3])")


@dataclass(frozen=True)
class SeedOptions:
    """How the seed method runs: the config's ``optimise.seed`` block.

    Attributes
    ----------
    k_iterations : int
        Iterations of steps a)-c) (the chapter: 50).
    f_init_px : None or float or (float, float)
        Starting (fx, fy), px; None starts from K (step 1 of the chapter).
    objective : {"summed", "sum_abs", "sum_squares"}
        Objective of step c) (:mod:`cvsflow.optimise.seed`); ``summed`` is eq. 1.12 literally.
    grid_half_width_px : float
        Half width of the first grid level around the current (fx, fy), px.
    grid_points : int
        Odd number of grid points per axis and level (the current point is on the grid).
    grid_levels : int
        Coarse-to-fine levels: level l+1 is centred on level l's best and its half width is
        level l's step ``2 h_l / (grid_points - 1)`` (32 px, 5 points, 6 levels: steps 16, 8,
        4, 2, 1, 0.5 px). The search is local: one iteration moves f by at most sum_l h_l.
    f_bounds_px : (float, float)
        Candidates outside these bounds are skipped, px.
    n_workers : int
        Threads sharing the chunks of each level's stacked PnP (numpy releases the GIL); the
        result does not depend on it.
    gn_max_iter : int
        Gauss-Newton iterations of each candidate's PnP.
    gn_tol : float
        Its step tolerance, rad and metres.
    """

    k_iterations: int = 50
    f_init_px: object = None
    objective: str = "sum_squares"
    grid_half_width_px: float = 32.0
    grid_points: int = 5
    grid_levels: int = 6
    f_bounds_px: tuple = (100.0, 5000.0)
    n_workers: int = 1
    gn_max_iter: int = 10
    gn_tol: float = 1e-6

    @classmethod
    def build(cls, options=None, **overrides):
        """Options checked, with ``overrides`` (field names) applied.

        Parameters
        ----------
        options : SeedOptions or dict, optional
            The starting options (a dict: the config block); default the class defaults.
        **overrides
            Fields to change.

        Returns
        -------
        SeedOptions

        Raises
        ------
        OptimiseError
            An unknown option, or a value out of its range.
        """
        opts = build_options(cls, options, overrides, "seed")
        if opts.objective not in OBJECTIVES:
            raise OptimiseError(f"seed objective {opts.objective!r}: expected one of {OBJECTIVES}")
        if int(opts.grid_points) < 3 or int(opts.grid_points) % 2 == 0:
            raise OptimiseError(f"seed grid_points = {opts.grid_points}: expected an odd number >= 3")
        if int(opts.grid_levels) < 1 or not opts.grid_half_width_px > 0 or int(opts.k_iterations) < 0:
            raise OptimiseError(
                f"seed grid: levels {opts.grid_levels}, half width {opts.grid_half_width_px} px, "
                f"k {opts.k_iterations}: expected levels >= 1, half width > 0, k >= 0"
            )
        return opts

    @property
    def first_step_px(self):
        """The first grid level's step, px: a focal length within it of a bound was stopped by the bound."""
        return 2.0 * float(self.grid_half_width_px) / (int(self.grid_points) - 1)


@dataclass
class SeedInputs:
    """The pairs and corners the search runs on, checked (:func:`seed_inputs`).

    Attributes
    ----------
    pairs : DataFrame
        The pairs with the whole board, sorted by frame.
    frames : ndarray of int, shape (N,)
    uv : ndarray, shape (N, P, 2)
        Their corners, px.
    X_B : ndarray, shape (P, 3)
        The board's corners in B, metres.
    P_star : ndarray, shape (N, 6)
        The mocap 6-vectors P* (eq. 1.5), m and rad.
    R0, t0 : ndarray, shapes (N, 3, 3) and (N, 3)
        The PnP poses T_C_B at the calibrated K (the first warm start), metres.
    K : ndarray, shape (3, 3)
    d5 : ndarray, shape (5,)
    f0 : ndarray, shape (2,)
        The starting (fx, fy), px.
    cache_rows : ndarray of int or None
        The pairs' rows in the pose cache.
    """

    pairs: pd.DataFrame
    frames: np.ndarray
    uv: np.ndarray
    X_B: np.ndarray
    P_star: np.ndarray
    R0: np.ndarray
    t0: np.ndarray
    K: np.ndarray
    d5: np.ndarray
    f0: np.ndarray
    cache_rows: object = None


def seed_inputs(pairs, corners, K, dist, board, opts, pose_cache=None):
    """Check and read what the seed method runs on.

    Parameters
    ----------
    pairs, corners, K, dist, board
        As :func:`cvsflow.optimise.seed.optimise_seed`.
    opts : SeedOptions
    pose_cache : SeedPoseCache, optional
        Bound to the camera and the PnP settings here; the corners come from it.

    Returns
    -------
    SeedInputs

    Raises
    ------
    OptimiseError
        Missing columns, too few pairs, a bad K, duplicate frames, a non-finite mocap pose.
    WholeBoardError
        Too few pairs with the whole board.
    """
    cvs_cols = [f"cvs_{d}" for d in ERROR_DIMS] + [f"cvs_rvec_{i}" for i in range(3)]
    vic_cols = [f"vic_{d}" for d in ERROR_DIMS]
    missing = {"frame", *cvs_cols, *vic_cols} - set(pairs.columns)
    if missing:
        raise OptimiseError(f"pairs.parquet: missing columns {sorted(missing)}")
    if len(pairs) < MIN_PAIRS:
        raise OptimiseError(f"pairs.parquet: {len(pairs)} pairs; the seed optimiser needs at least "
                            f"{MIN_PAIRS}")
    K = np.asarray(K, dtype=float)
    if K.shape != (3, 3):
        raise OptimiseError(f"camera K: shape {K.shape}, expected (3, 3)")
    if opts.f_init_px is None:
        f = np.array([K[0, 0], K[1, 1]], dtype=float)
    else:
        f = np.broadcast_to(np.asarray(opts.f_init_px, dtype=float), (2,)).copy()
    if not np.all(f > 0):
        raise OptimiseError(f"seed f_init_px = {f.tolist()}: focal lengths must be > 0 px")
    pairs = pairs.sort_values("frame").reset_index(drop=True)
    frames = pairs["frame"].to_numpy(dtype=np.int64)
    if np.unique(frames).size != frames.size:
        raise OptimiseError("pairs.parquet: duplicate frame numbers")
    X_B = board_object_points(board)
    cache_rows = None
    if pose_cache is None:
        uv = corner_array(corners, frames, X_B.shape[0], allow_partial=True)
    else:
        pose_cache.bind(K, dist, board, opts.gn_max_iter, opts.gn_tol)
        cache_rows = pose_cache.positions(pairs)
        uv = pose_cache.uv_px[cache_rows]
    # The chapter re-estimates every pose at each candidate f from the whole board; frames
    # where a hand or the image border hid some corners are left to se3.
    complete = np.isfinite(uv).all(axis=(1, 2))
    if not complete.all():
        log.warning("seed: %d of %d pairs have only part of the board's corners; left out",
                    int((~complete).sum()), len(frames))  # fmt: skip
        pairs, frames, uv = pairs[complete].reset_index(drop=True), frames[complete], uv[complete]
        if cache_rows is not None:
            cache_rows = cache_rows[complete]
        if len(pairs) < MIN_PAIRS:
            raise WholeBoardError(
                f"pairs.parquet: {len(pairs)} pairs with the whole board (a hand or the image "
                f"border hides part of it in the other {int((~complete).sum())}); the seed "
                f"optimiser (the chapter's method) needs at least {MIN_PAIRS}. {SE3_ALONE}"
            )
    P_star = pairs[vic_cols].to_numpy(dtype=float)
    if not np.isfinite(P_star).all():
        bad = int(frames[np.argmax(~np.isfinite(P_star).all(axis=1))])
        raise OptimiseError(f"pairs.parquet: frame {bad}: non-finite Vicon pose vic_*")
    R0 = R_from_rvec(pairs[[f"cvs_rvec_{i}" for i in range(3)]].to_numpy(dtype=float))
    t0 = pairs[[f"cvs_{d}" for d in ERROR_DIMS[:3]]].to_numpy(dtype=float)
    return SeedInputs(pairs, frames, uv, X_B, P_star, R0, t0, K, dist5(dist), f, cache_rows)


def corner_array(corners, frames, n_corners, allow_partial=False):
    """Pixel corners of the given frames as one array.

    Parameters
    ----------
    corners : pandas.DataFrame
        ``corners.parquet``: ``frame, found, corner, u_px, v_px``.
    frames : array_like of int, shape (N,)
        Frames wanted, in order.
    n_corners : int
        Inner corners per board (P).
    allow_partial : bool
        Accept frames that hold only some of the corners (NaN rows for the others).

    Returns
    -------
    uv_px : ndarray, shape (N, P, 2)
        Distorted pixel positions, corner k in row k.

    Raises
    ------
    OptimiseError
        A frame is missing or not found, or (unless ``allow_partial``) lacks a corner.
    """
    missing_cols = {"frame", "corner", "u_px", "v_px"} - set(corners.columns)
    if missing_cols:
        raise OptimiseError(f"corners.parquet: missing columns {sorted(missing_cols)}")
    frames = np.asarray(frames, dtype=np.int64)
    c = corners
    if "found" in c.columns:
        c = c[c["found"].astype(bool)]
    c = c[(c["corner"] >= 0) & (c["corner"] < n_corners)]
    c = c[c["frame"].isin(frames)]
    c = c.drop_duplicates(["frame", "corner"])
    wide = c.pivot(index="frame", columns="corner", values=["u_px", "v_px"])
    wide = wide.reindex(index=frames)
    uv = np.full((frames.size, n_corners, 2), np.nan)
    for j, col in enumerate(("u_px", "v_px")):
        if col in wide.columns.get_level_values(0):
            block = wide[col].reindex(columns=range(n_corners))
            uv[:, :, j] = block.to_numpy(dtype=float)
    bad = ~np.isfinite(uv).all(axis=(1, 2))
    if allow_partial:
        bad = ~np.isfinite(uv).all(axis=2).any(axis=1)
    if bad.any():
        first = int(frames[np.argmax(bad)])
        raise OptimiseError(
            f"corners.parquet: frame {first} (and {int(bad.sum()) - 1} more) of pairs.parquet "
            + ("has no found corner with finite u_px, v_px" if allow_partial else
               f"has no complete set of {n_corners} found corners with finite u_px, v_px")
        )
    return uv


# --------------------------------------------------------------------------- eqs. 1.10-1.12


class PoseSolver:
    """PnP of every frame at many candidate focal lengths, in stacks (a context manager: it
    owns the threads of ``n_workers``).

    Parameters
    ----------
    inputs : SeedInputs
    opts : SeedOptions
    pose_cache : SeedPoseCache, optional
        Rows solved before are taken from it, the others solved and added.
    """

    def __init__(self, inputs, opts, pose_cache=None):
        self.inputs, self.opts, self.pose_cache = inputs, opts, pose_cache
        self.pool = ThreadPoolExecutor(max_workers=int(opts.n_workers)) if int(opts.n_workers) > 1 else None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        if self.pool is not None:
            self.pool.shutdown()

    def _stack(self, frame_rows, fx_rows, fy_rows, R_start, t_start):
        """Poses of (candidate, frame) rows: one batched solve."""
        i, o = self.inputs, self.opts
        return solve_rows(i.uv, frame_rows, i.X_B, fx_rows, fy_rows, float(i.K[0, 2]), float(i.K[1, 2]),
                          i.d5, R_start, t_start, o.gn_max_iter, o.gn_tol, pool=self.pool,
                          n_workers=o.n_workers)  # fmt: skip

    def solve(self, cands, R_start, t_start, walk):
        """Poses (C, N, 3, 3), (C, N, 3) of every frame at every candidate (fx, fy) (C, 2), px,
        reached along ``walk`` (the focal lengths visited: with a candidate they fix its warm
        starts, the pose cache's key)."""
        n = len(self.inputs.frames)
        cands = np.asarray(cands, dtype=float).reshape(-1, 2)
        if self.pose_cache is None:
            Rc, tc = self._stack(np.tile(np.arange(n), len(cands)), np.repeat(cands[:, 0], n),
                                 np.repeat(cands[:, 1], n), R_start, t_start)  # fmt: skip
        else:
            Rc, tc = self.pose_cache.solve(walk, cands, self.inputs.cache_rows, R_start, t_start, self._stack)
        return Rc.reshape(len(cands), n, 3, 3), tc.reshape(len(cands), n, 3)


def grid_search(solver, f, R, t, P_bar, walk, objective_value):
    """Step c), eq. 1.12: the coarse-to-fine grid search of (fx, fy) with P_bar held.

    Parameters
    ----------
    solver : PoseSolver
    f : ndarray, shape (2,)
        The current (fx, fy), px.
    R, t : ndarray, shapes (N, 3, 3) and (N, 3)
        The poses at f, metres.
    P_bar : ndarray, shape (6,)
        Step a)'s offset, m and rad.
    walk : tuple of (float, float)
        The focal lengths visited so far.
    objective_value : callable
        ``objective_value(eps_xyz_m, objective)`` (:func:`cvsflow.optimise.seed.objective_value`).

    Returns
    -------
    best : (float, ndarray, ndarray, ndarray)
        The least objective, its (fx, fy), px, and its poses R, t.
    n_solves : int
        Candidates solved.
    """
    inp, opts = solver.inputs, solver.opts
    dtheta_df = focal_sensitivity(inp.uv, inp.X_B, f[0], f[1], float(inp.K[0, 2]), float(inp.K[1, 2]),
                                  inp.d5, R, t)  # fmt: skip
    target = inp.P_star[:, :3] + P_bar[:3]

    def score(cands):
        """Objective and poses at each candidate; all candidates solved in one stack."""
        out = [None] * len(cands)
        moved = []
        for i, fxy in enumerate(cands):
            df = fxy - f
            if not np.any(df):
                out[i] = (objective_value(t - target, opts.objective), R, t)
            else:
                step = dtheta_df @ df  # first-order warm start, (N, 6)
                moved.append((i, R_from_rvec(step[:, :3]) @ R, t + step[:, 3:]))
        if moved:
            Rc, tc = solver.solve([cands[i] for i, _, _ in moved], np.concatenate([m[1] for m in moved]),
                                  np.concatenate([m[2] for m in moved]), walk)  # fmt: skip
            for k, (i, _, _) in enumerate(moved):
                out[i] = (objective_value(tc[k] - target, opts.objective), Rc[k], tc[k])
        return out

    best = (objective_value(t - target, opts.objective), f.copy(), R, t)
    centre, half, seen, n_solves = f.copy(), float(opts.grid_half_width_px), {tuple(f)}, 0
    lo, hi = opts.f_bounds_px
    for _level in range(int(opts.grid_levels)):
        cands = [c for c in _grid(centre, half, int(opts.grid_points))
                 if tuple(c) not in seen and lo <= c[0] <= hi and lo <= c[1] <= hi]
        seen.update(tuple(c) for c in cands)
        n_solves += len(cands)
        for c, (val, Rc, tc) in zip(cands, score(cands), strict=True):
            if val < best[0]:
                best = (val, c.copy(), Rc, tc)
        centre = best[1]
        half = 2.0 * half / (int(opts.grid_points) - 1)
    return best, n_solves


def _grid(centre, half_width, n_points):
    """(fx, fy) candidates on an n x n grid centred on ``centre`` (always included)."""
    offsets = np.linspace(-half_width, half_width, n_points)
    gx, gy = np.meshgrid(centre[0] + offsets, centre[1] + offsets, indexing="ij")
    return np.stack([gx.ravel(), gy.ravel()], axis=1)
