"""PnP poses the seed optimiser solved, shared by its runs on subsets of one session's frames.

:func:`cvsflow.evaluate.heldout_seed.cross_validate_seed` runs :func:`cvsflow.optimise.seed.optimise_seed`
once per fold, on all the session's pairs but that fold's. Every run starts at the calibrated
focal lengths from the same poses, so the first iteration's grid solves the same frames at
the same candidates from the same warm starts in every fold. What one frame's solve returns
depends on that frame alone (its corners and start pose), the camera, and the focal lengths
the run has walked so far (the warm start is the pose at the current focal lengths moved by
its first-order sensitivity): every row of :mod:`cvsflow.optimise.seed_pnp`'s stacks is
computed independently of the others. So a pose solved in one fold is, bit for bit, the one
another fold would solve on the same walk; :class:`SeedPoseCache` keeps them, keyed by the
walk and the candidate, and a later fold solves only the frames no earlier fold had.

The first iteration is shared by all folds; deeper iterations only while two folds walked the
same focal lengths (on the 20 s demo the folds part after the first, 9 % of the rows are
shared; on a 90 s render they walk together longer, 24 %). The entries of the longest walks
are dropped first when the cache outgrows ``max_bytes``: they are the least likely to be
walked again.
"""

from __future__ import annotations

import numpy as np

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.optimise.seed_pnp import dist5
from cvsflow.optimise.seed_search import corner_array

#: Bytes of cached poses at most (default of :class:`SeedPoseCache`): a 90 s session's
#: 2,700 pairs take 0.26 MB per (walk, candidate) entry, and its cross-validation (5 folds,
#: 10 iterations) made 893 entries, 234 MB; with 64 MB it shared 417k rows instead of 587k.
MAX_BYTES = 256_000_000

#: The pairs columns a run's start poses come from (rotation vector, then translation, T_C_B).
START_COLUMNS = ("cvs_rvec_0", "cvs_rvec_1", "cvs_rvec_2", "cvs_x_m", "cvs_y_m", "cvs_z_m")


class SeedPoseCache:
    """Poses T_C_B of a session's pair frames at each (walk, candidate focal lengths) solved.

    Parameters
    ----------
    pairs : pandas.DataFrame
        ``pairs.parquet`` of the whole session (every run's pairs are a subset of its rows);
        ``frame`` and the start pose columns :data:`START_COLUMNS`.
    corners : pandas.DataFrame
        ``corners.parquet``; the pixel corners of every pair frame are read once here
        (:func:`cvsflow.optimise.seed_search.corner_array`, frames with part of the board as NaN rows).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    max_bytes : int
        Bytes of poses kept at most (:data:`MAX_BYTES`).

    Attributes
    ----------
    frames : ndarray of int, shape (N,)
        The session's pair frames, sorted.
    uv_px : ndarray, shape (N, P, 2)
        Their distorted pixel corners.
    n_solved, n_reused : int
        (Candidate, frame) rows solved and rows taken from the cache, so far.

    Notes
    -----
    A cache belongs to one camera and one set of PnP settings: the first run that uses it
    binds them (:meth:`bind`), a later run with others is an error.
    """

    def __init__(self, pairs, corners, board, max_bytes=MAX_BYTES):
        missing = {"frame", *START_COLUMNS} - set(pairs.columns)
        if missing:
            raise OptimiseError(f"pairs.parquet: missing columns {sorted(missing)}")
        ordered = pairs.sort_values("frame")
        self.frames = ordered["frame"].to_numpy(dtype=np.int64)
        if np.unique(self.frames).size != self.frames.size:
            raise OptimiseError("pairs.parquet: duplicate frame numbers")
        self.X_B = board_object_points(board)
        self.uv_px = corner_array(corners, self.frames, self.X_B.shape[0], allow_partial=True)
        self._start = ordered[list(START_COLUMNS)].to_numpy(dtype=float)
        self.max_bytes = int(max_bytes)
        self.n_solved = 0
        self.n_reused = 0
        self._context = None
        self._entries = {}  # (walk, candidate) -> [R (N, 3, 3), t (N, 3), solved (N,)]
        self._entry_bytes = self.frames.size * (12 * 8 + 1)

    def positions(self, pairs):
        """Rows of the cache of a run's pairs, checked against the cache's start poses.

        Parameters
        ----------
        pairs : pandas.DataFrame
            The run's pairs, sorted by frame (as :func:`optimise_seed` sorts them).

        Returns
        -------
        ndarray of int, shape (n,)
            Index of each pair frame in :attr:`frames`.

        Raises
        ------
        OptimiseError
            A frame the cache does not hold, or a start pose that differs from the cache's.
        """
        frames = pairs["frame"].to_numpy(dtype=np.int64)
        pos = np.clip(np.searchsorted(self.frames, frames), 0, self.frames.size - 1)
        bad = self.frames[pos] != frames
        if bad.any():
            raise OptimiseError(f"seed pose cache: frame {int(frames[np.argmax(bad)])} of the "
                                "run's pairs is not among the session's pairs it was built from")
        start = pairs[list(START_COLUMNS)].to_numpy(dtype=float)
        if not np.array_equal(start, self._start[pos], equal_nan=True):
            raise OptimiseError("seed pose cache: the run's pairs have other start poses "
                                f"({', '.join(START_COLUMNS)}) than the pairs it was built from")
        return pos

    def bind(self, K, dist, board, gn_max_iter, gn_tol):
        """Tie the cache to one camera and PnP setting; raise if a run brings others.

        Parameters
        ----------
        K : array_like, shape (3, 3)
            Camera matrix, px (only cx, cy are used by the solves; fx, fy are the candidates').
        dist : array_like
            OpenCV distortion.
        board : dict
            The board of the run.
        gn_max_iter, gn_tol : int, float
            The run's PnP limits.

        Raises
        ------
        OptimiseError
            The cache was bound to another camera, board or PnP setting.
        """
        K = np.asarray(K, dtype=float)
        context = (float(K[0, 2]), float(K[1, 2]), dist5(dist).tobytes(),
                   board_object_points(board).tobytes(), int(gn_max_iter), float(gn_tol))
        if self._context is None:
            self._context = context
        elif context != self._context:
            raise OptimiseError("seed pose cache: a run with another camera (cx, cy, "
                                "distortion), board or PnP limits than the cache was bound to")

    def solve(self, walk, cands_px, pos, R_start, t_start, solve_stack):
        """Poses of a run's frames at each candidate; only the rows not cached are solved.

        Parameters
        ----------
        walk : tuple
            The focal lengths the run has visited, ``((fx, fy), ...)`` in px (empty for the
            start solve from the pairs' poses): with the candidate, the key of an entry.
        cands_px : ndarray, shape (C, 2)
            Candidate (fx, fy), px.
        pos : ndarray of int, shape (n,)
            The run's frames as rows of the cache (:meth:`positions`).
        R_start, t_start : ndarray, shape (C n, 3, 3) and (C n, 3)
            Warm starts, candidate-major (row ``k n + i``: candidate k, the run's frame i).
        solve_stack : callable
            ``solve_stack(frame_rows, fx_rows, fy_rows, R, t) -> (R, t)``: the run's batched
            PnP of (candidate, frame) rows (:func:`cvsflow.optimise.seed_pnp.solve_rows`).

        Returns
        -------
        R, t : ndarray, shape (C n, 3, 3) and (C n, 3)
            Poses T_C_B, candidate-major, metres.
        """
        n = pos.size
        entries = [self._entry(walk, c) for c in cands_px]
        todo = [np.arange(n) if e is None else np.flatnonzero(~e[2][pos]) for e in entries]
        rows = np.concatenate([k * n + i for k, i in enumerate(todo)])
        R = np.empty((len(cands_px) * n, 3, 3))
        t = np.empty((len(cands_px) * n, 3))
        if rows.size:
            k_of_row = rows // n
            R[rows], t[rows] = solve_stack(rows % n, cands_px[k_of_row, 0], cands_px[k_of_row, 1],
                                           R_start[rows], t_start[rows])
        for k, (e, i) in enumerate(zip(entries, todo, strict=True)):
            block = slice(k * n, (k + 1) * n)
            if e is None:
                continue
            e[0][pos[i]], e[1][pos[i]], e[2][pos[i]] = R[block][i], t[block][i], True
            hit = np.ones(n, bool)
            hit[i] = False
            R[block][hit], t[block][hit] = e[0][pos[hit]], e[1][pos[hit]]
        self.n_solved += int(rows.size)
        self.n_reused += len(cands_px) * n - int(rows.size)
        return R, t

    def _entry(self, walk, cand):
        """The entry of (walk, candidate), made if room is left or made by dropping longer walks."""
        key = (walk, (float(cand[0]), float(cand[1])))
        if key in self._entries:
            return self._entries[key]
        while (len(self._entries) + 1) * self._entry_bytes > self.max_bytes:
            longest = max(self._entries, key=lambda k: len(k[0]), default=None)
            if longest is None or len(longest[0]) <= len(walk):
                return None  # full of walks as short as this one: solve without keeping
            del self._entries[longest]
        n = self.frames.size
        entry = [np.empty((n, 3, 3)), np.empty((n, 3)), np.zeros(n, bool)]
        self._entries[key] = entry
        return entry
