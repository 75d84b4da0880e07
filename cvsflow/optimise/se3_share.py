"""What the se3 fits of one session have in common, computed once (:class:`Se3Share`).

The held-out scoring (:func:`cvsflow.evaluate.heldout.cross_validate_se3`) fits se3 on every
fold's training frames and scores its held-out frames: each fold used to read the corners
table into arrays again, build both body tracks again (smoothing, the static test and the
interpolant: about a quarter of the job) and solve PnP again at the calibration for the
hand-eye start. None of these depends on the fold: the arrays and the tracks are functions of
the tables and the smoothing options, and a frame's PnP pose (:func:`solve_pnp_frames`) is a
function of that frame's corners and the camera alone. So the folds take them from one
:class:`Se3Share`, and every fold's result is the one it had on its own, bit for bit.
"""

from __future__ import annotations

import numpy as np

from cvsflow.board import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.optimise.body_tracks import BodyTrack
from cvsflow.optimise.se3_start import corner_arrays, solve_pnp_frames


class Se3Share:
    """Corner arrays, body tracks and per-frame PnP poses of one session, made once.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet of the session.
    bodies : DataFrame
        bodies.parquet of the session (native rate).
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.

    Attributes
    ----------
    frame : ndarray of int, shape (F,)
    t_video : ndarray, shape (F,)
        Video times, s.
    uv : ndarray, shape (F, P, 2)
        :func:`~cvsflow.optimise.se3_start.corner_arrays` of ``corners``, px.
    p_B : ndarray, shape (P, 3)
        The board's corners in B, m.
    n_pnp_solved, n_pnp_reused : int
        Frames solved by PnP, and frames taken from earlier solves, so far.
    """

    def __init__(self, corners, bodies, board):
        self.corners, self.bodies = corners, bodies
        self.p_B = board_object_points(board)
        self.frame, self.t_video, self.uv = corner_arrays(corners, len(self.p_B))
        self._tracks = {}
        self._pnp = {}
        self.n_pnp_solved = 0
        self.n_pnp_reused = 0

    def check(self, corners, bodies, board):
        """Raise unless a fit's tables are the ones this share was made from.

        Parameters
        ----------
        corners, bodies : DataFrame
            The fit's tables (the same objects).
        board : dict

        Raises
        ------
        OptimiseError
            Other tables or another board.
        """
        if corners is not self.corners or bodies is not self.bodies:
            raise OptimiseError("se3 share: a fit's corners or bodies table is not the one the "
                                "share was made from")
        if not np.array_equal(board_object_points(board), self.p_B):
            raise OptimiseError("se3 share: a fit's board is not the one the share was made from")

    def track(self, body, **options):
        """:meth:`BodyTrack.from_bodies` of the session's bodies, made once per body and options.

        Parameters
        ----------
        body : str
            ``"camera"`` or ``"board"``.
        **options
            ``smooth_s``, ``static_tol``, ``moving_smooth_s``.

        Returns
        -------
        BodyTrack
            Shared by every caller with the same options: read it, do not change it.
        """
        key = (body, tuple(sorted((k, None if v is None else tuple(np.ravel(v).tolist()))
                                  for k, v in options.items())))
        if key not in self._tracks:
            self._tracks[key] = BodyTrack.from_bodies(self.bodies, body, **options)
        return self._tracks[key]

    def rows(self, frames):
        """Rows of :attr:`frame` of the given frames (each must be one of them).

        Parameters
        ----------
        frames : array_like of int, shape (n,)

        Returns
        -------
        ndarray of int, shape (n,)
        """
        frames = np.asarray(frames, dtype=np.int64)
        pos = np.clip(np.searchsorted(self.frame, frames), 0, max(self.frame.size - 1, 0))
        if frames.size and not np.array_equal(self.frame[pos], frames):
            raise OptimiseError("se3 share: a frame asked for has no corners in the share")
        return pos

    def pnp(self, rows, K, dist):
        """PnP poses T_C_B of the given rows at a camera; each row solved once per camera.

        Parameters
        ----------
        rows : ndarray of int, shape (n,)
            Rows of :attr:`frame` (:meth:`rows`).
        K : array_like, shape (3, 3)
            Camera matrix, px.
        dist : array_like, shape (5,)
            [k1, k2, p1, p2, k3].

        Returns
        -------
        T_C_B : ndarray, shape (n, 4, 4)
            Board in camera, m; NaN where PnP failed.
        ok : ndarray of bool, shape (n,)
            As :func:`~cvsflow.optimise.se3_start.solve_pnp_frames`.
        """
        K = np.asarray(K, np.float64)
        dist = np.asarray(dist, np.float64).ravel()
        key = (K.tobytes(), dist.tobytes())
        if key not in self._pnp:
            n = self.frame.size
            self._pnp[key] = (np.full((n, 4, 4), np.nan), np.zeros(n, bool), np.zeros(n, bool))
        T, ok, done = self._pnp[key]
        rows = np.asarray(rows, dtype=np.int64)
        todo = np.unique(rows[~done[rows]])
        if todo.size:
            T[todo], ok[todo] = solve_pnp_frames(self.uv[todo], self.p_B, K, dist)
            done[todo] = True
        self.n_pnp_solved += int(todo.size)
        self.n_pnp_reused += int(rows.size - todo.size)
        return T[rows].copy(), ok[rows].copy()
