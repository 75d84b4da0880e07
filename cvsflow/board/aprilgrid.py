"""Kalibr AprilGrid targets: the grid of AprilTags, its frame B and its corner ids.

Config ``board: {type: aprilgrid, tag_cols, tag_rows, tag_size_m, tag_spacing}`` (Kalibr's
``tagCols``, ``tagRows``, ``tagSize``, ``tagSpacing``; :mod:`cvsflow.board.kalibr` reads
Kalibr's target files). Finding the grid in an image is :mod:`cvsflow.board.aprilgrid_detect`.

Target frame B (Kalibr's, ``GridCalibrationTargetAprilgrid``)
-------------------------------------------------------------
Seen from the printed face, x points right and y up; z = x cross y points out of the face,
towards a camera that sees it. This differs from the chessboard's frame
(:mod:`cvsflow.board.model`: z into the board), so a camera seeing an AprilGrid has
``R_C_B[2, 2] < 0``. Tag ``t`` sits at column ``t % tag_cols``, row ``t // tag_cols`` (ids
row-major from the bottom-left); its black square, border included, spans
``[c p, c p + s] x [r p, r p + s]`` with ``s = tag_size_m`` and pitch ``p = s (1 + tag_spacing)``.
The origin is the outer corner of tag 0's black square.

Corner ids
----------
Corner ``4 t + k`` is corner ``k`` of tag ``t``: k = 0 bottom-left, 1 bottom-right, 2 top-right,
3 top-left in B (counter-clockwise seen from the front), the order of Kalibr's detector output.
Row ``i`` of :meth:`AprilGrid.object_points` is corner id ``i``, so the corners table, PnP and
the calibration take AprilGrid corners as they take a ChArUco board's: a frame has the ids it
saw. Kalibr stores the same points in a ``2 tag_rows x 2 tag_cols`` row-major grid;
:meth:`AprilGrid.kalibr_point_index` converts.

The printed tag
---------------
``tag_size_m`` is the black square edge to edge: 6 x 6 data bits and a black border of
``border_bits`` = 2 bits (Kalibr's ``blackTagBorder``, not the 1 bit of AprilRobotics'
printouts), so a bit is ``tag_size_m / 10``. Kalibr prints a black square of side
``tag_spacing * tag_size_m`` diagonally at every tag corner, so every tag corner is an X
junction (tag border, gap, corner square, gap), which the sub-pixel refinement locks on to.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from cvsflow.exceptions import ConfigError

#: Data bits across a tag of each family an AprilGrid can use (Kalibr decodes tag36h11 only).
FAMILY_DATA_BITS = {"tag36h11": 6}
#: Codes (ids) of each family.
FAMILY_N_CODES = {"tag36h11": 587}
#: Black border of a Kalibr tag, bits (``AprilgridOptions::blackTagBorder``).
KALIBR_BORDER_BITS = 2
#: Fewest tags a frame needs (Kalibr's ``minTagsForValidObs``): with 3 or more, the homography
#: (8 parameters) through their 12 or more corners is over-determined, so a wrong tag shows.
MIN_TAGS = 4
#: The keys of a ``type: aprilgrid`` board block (``border_bits`` and ``family`` optional).
APRILGRID_KEYS = ("tag_cols", "tag_rows", "tag_size_m", "tag_spacing")


def _is_number(value) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(value, bool)


@dataclass(frozen=True)
class AprilGrid:
    """A Kalibr AprilGrid: ``tag_cols x tag_rows`` tags, ids row-major from the bottom-left.

    Attributes
    ----------
    tag_cols, tag_rows : int
        Tags along B's x and y (Kalibr ``tagCols``, ``tagRows``).
    tag_size_m : float
        Edge of a tag's black square, border included, metres (Kalibr ``tagSize``).
    tag_spacing : float
        Gap between two tags as a share of ``tag_size_m`` (Kalibr ``tagSpacing``), in (0, 1].
    family : str
        AprilTag family, ``"tag36h11"``.
    border_bits : int
        Black border of a tag, bits (2 for Kalibr's printouts).

    Raises
    ------
    ConfigError
        A value out of its range (named), fewer than ``MIN_TAGS - 1`` tags, or more tags than
        the family has ids.
    """

    tag_cols: int
    tag_rows: int
    tag_size_m: float
    tag_spacing: float
    family: str = "tag36h11"
    border_bits: int = KALIBR_BORDER_BITS

    def __post_init__(self):
        for name in ("tag_cols", "tag_rows", "border_bits"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
                raise ConfigError(f"AprilGrid: {name}={value!r}; expected an integer >= 1")
        if self.family not in FAMILY_DATA_BITS:
            raise ConfigError(
                f"AprilGrid: family={self.family!r}; expected one of {sorted(FAMILY_DATA_BITS)}"
            )
        if self.n_tags < MIN_TAGS - 1:
            raise ConfigError(
                f"AprilGrid: {self.tag_cols}x{self.tag_rows} tags; expected at least "
                f"{MIN_TAGS - 1} tags for the grid's consistency check"
            )
        if self.n_tags > FAMILY_N_CODES[self.family]:
            raise ConfigError(
                f"AprilGrid: {self.n_tags} tags but {self.family} has only "
                f"{FAMILY_N_CODES[self.family]} ids"
            )
        if not (_is_number(self.tag_size_m) and math.isfinite(self.tag_size_m) and self.tag_size_m > 0):
            raise ConfigError(f"AprilGrid: tag_size_m={self.tag_size_m!r}; expected a length > 0 m")
        if not (_is_number(self.tag_spacing) and 0.0 < self.tag_spacing <= 1.0):
            raise ConfigError(
                f"AprilGrid: tag_spacing={self.tag_spacing!r}; expected the ratio gap / tag_size "
                "in (0, 1] (Kalibr's tagSpacing, e.g. 0.3), not a gap in metres"
            )

    @property
    def n_tags(self) -> int:
        """Tags on the grid."""
        return self.tag_cols * self.tag_rows

    @property
    def n_corners(self) -> int:
        """Corners on the grid (4 per tag)."""
        return 4 * self.n_tags

    @property
    def pitch_m(self) -> float:
        """Distance between neighbouring tags' origins, metres."""
        return self.tag_size_m * (1.0 + self.tag_spacing)

    @property
    def tag_bits(self) -> int:
        """Bits across a tag's black square (data bits and both borders): 10 for Kalibr."""
        return FAMILY_DATA_BITS[self.family] + 2 * self.border_bits

    def object_points(self) -> np.ndarray:
        """Every corner of the grid in the target frame B.

        Returns
        -------
        p_B : ndarray, shape (4 * n_tags, 3), float64
            Row ``i`` is corner id ``i`` (tag ``i // 4``, corner ``i % 4``), metres, z = 0.
        """
        t = np.arange(self.n_tags)
        origin = np.stack([(t % self.tag_cols) * self.pitch_m, (t // self.tag_cols) * self.pitch_m], 1)
        offsets = self.tag_size_m * np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
        xy = (origin[:, None, :] + offsets[None, :, :]).reshape(-1, 2)
        return np.column_stack([xy, np.zeros(len(xy))])

    def tag_centres(self) -> np.ndarray:
        """Centre of every tag in B.

        Returns
        -------
        c_B : ndarray, shape (n_tags, 3), float64
            Row ``t`` is tag ``t``'s centre, metres, z = 0.
        """
        return self.object_points().reshape(self.n_tags, 4, 3).mean(axis=1)

    def printed_extent_m(self) -> tuple[float, float, float, float]:
        """Extent of the print in B, the corner squares outside the outer tags included.

        Returns
        -------
        extent : (float, float, float, float)
            ``(x_min, x_max, y_min, y_max)``, metres.
        """
        gap = self.tag_spacing * self.tag_size_m
        return (-gap, (self.tag_cols - 1) * self.pitch_m + self.tag_size_m + gap,
                -gap, (self.tag_rows - 1) * self.pitch_m + self.tag_size_m + gap)

    def kalibr_point_index(self, corner_ids) -> np.ndarray:
        """Index of corners in Kalibr's point list (``GridCalibrationTargetAprilgrid::points``).

        Kalibr keeps the points in a ``(2 tag_rows) x (2 tag_cols)`` grid, row-major from the
        bottom-left: tag ``t`` (row r, column c), corner k is at grid row ``2 r + (k in {2, 3})``,
        column ``2 c + (k in {1, 2})``.

        Parameters
        ----------
        corner_ids : array_like of int, shape (M,)
            Corner ids ``4 t + k``.

        Returns
        -------
        index : ndarray, shape (M,), int64
        """
        ids = np.asarray(corner_ids, dtype=np.int64)
        t, k = ids // 4, ids % 4
        r, c = t // self.tag_cols, t % self.tag_cols
        return (2 * r + np.isin(k, (2, 3))) * (2 * self.tag_cols) + 2 * c + np.isin(k, (1, 2))

    def config(self) -> dict:
        """The grid's ``board`` block.

        Returns
        -------
        board : dict
            ``type: aprilgrid``, ``tag_cols``, ``tag_rows``, ``tag_size_m`` (m),
            ``tag_spacing`` (ratio); ``border_bits`` and ``family`` when not Kalibr's.
        """
        out = {"type": "aprilgrid", "tag_cols": int(self.tag_cols), "tag_rows": int(self.tag_rows),
               "tag_size_m": float(self.tag_size_m), "tag_spacing": float(self.tag_spacing)}
        if self.border_bits != KALIBR_BORDER_BITS:
            out["border_bits"] = int(self.border_bits)
        if self.family != "tag36h11":
            out["family"] = self.family
        return out


def aprilgrid_from_board(board: dict) -> AprilGrid:
    """The :class:`AprilGrid` of a ``type: aprilgrid`` board block.

    Parameters
    ----------
    board : dict
        ``tag_cols``, ``tag_rows`` (int), ``tag_size_m`` (m), ``tag_spacing`` (ratio gap /
        tag size); optional ``border_bits`` (default 2) and ``family`` (``tag36h11``).

    Returns
    -------
    AprilGrid

    Raises
    ------
    ConfigError
        A missing or invalid key, named with its value and what was expected.
    """
    missing = [k for k in APRILGRID_KEYS if k not in board]
    if missing:
        raise ConfigError(
            f"board {board!r}: type aprilgrid needs keys {missing} (tag_cols, tag_rows: tags "
            "along x and y; tag_size_m: a tag's black square in m; tag_spacing: gap / tag size, "
            "Kalibr's tagSpacing)"
        )
    unknown = sorted(set(board) - {"type", *APRILGRID_KEYS, "border_bits", "family"})
    if unknown:
        raise ConfigError(f"board: keys {unknown} are not AprilGrid keys (expected {list(APRILGRID_KEYS)}, "
                          "optional border_bits, family)")
    try:
        return AprilGrid(board["tag_cols"], board["tag_rows"], board["tag_size_m"], board["tag_spacing"],
                         family=board.get("family", "tag36h11"),
                         border_bits=board.get("border_bits", KALIBR_BORDER_BITS))
    except ConfigError as exc:
        raise ConfigError(f"board: {exc}") from exc
