"""Kalibr target files: what a ``target.yaml`` describes, as a cvsflow board.

Kalibr (``kalibr_common/ConfigReader.py``) names a calibration target in a small YAML file:

- ``target_type: aprilgrid`` with ``tagCols``, ``tagRows``, ``tagSize`` (m, a tag's black
  square edge to edge) and ``tagSpacing`` (the gap as a ratio of ``tagSize``): a
  :class:`cvsflow.board.aprilgrid.AprilGrid`, ``board: {type: aprilgrid, ...}``;
- ``target_type: checkerboard`` with ``targetCols``, ``targetRows`` (INNER corners) and
  ``rowSpacingMeters``, ``colSpacingMeters``: a cvsflow chessboard of ``targetCols + 1`` by
  ``targetRows + 1`` squares (cvsflow counts squares), which needs square squares.

Two other spellings of an AprilGrid are read too: yac's (a ``calib_target`` block with
``tag_cols``, ``tag_rows``, ``tag_size``, ``tag_spacing``) and ETH ``hand_eye_calibration``'s
(``april_tag_number_horizontal``, ``..._vertical``, ``april_tag_size_m``, ``april_tag_gap_size_m``:
a gap in metres, so ratio = gap / size, and ``april_tag_number_pixel_boarder``, the border bits).
Kalibr's ``circlegrid`` has no cvsflow board and is refused by name.

A Kalibr checkerboard's frame is not cvsflow's chessboard frame B: Kalibr puts its point
``r * targetCols + c`` (OpenCV's corner order, the same index in both) at
``(r * rowSpacingMeters, c * colSpacingMeters, 0)``, rows along x, while cvsflow puts corner
``k`` at ``((k % nx) s, (k // nx) s, 0)``, rows along y. Hence ``p_B = R_B_K p_K`` with
``R_B_K`` = :data:`R_B_KALIBR_CHECKERBOARD` (x and y swapped, z turned: a rotation), and a pose
of Kalibr's target is ``T_C_K = T_C_B diag(R_B_K, 1)``. Kalibr's AprilGrid frame is cvsflow's
AprilGrid frame itself.

This module takes the file's parsed content; ``cvsflow.io.targets.read_kalibr_target`` reads
the file.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from cvsflow.board.aprilgrid import KALIBR_BORDER_BITS, AprilGrid
from cvsflow.exceptions import ConfigError

#: ``p_B = R_B_KALIBR_CHECKERBOARD @ p_K``: a point of Kalibr's checkerboard frame K in cvsflow's
#: chessboard frame B (the same corner index in both).
R_B_KALIBR_CHECKERBOARD = np.array([[0.0, 1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, -1.0]])

#: Kalibr's ``target_type`` values cvsflow reads.
KALIBR_TARGET_TYPES = ("aprilgrid", "checkerboard")

# Keys of each spelling, in the AprilGrid's order (cols, rows, size, spacing).
_KALIBR_APRILGRID_KEYS = ("tagCols", "tagRows", "tagSize", "tagSpacing")
_YAC_APRILGRID_KEYS = ("tag_cols", "tag_rows", "tag_size", "tag_spacing")
_KALIBR_CHECKERBOARD_KEYS = ("targetCols", "targetRows", "rowSpacingMeters", "colSpacingMeters")
_HAND_EYE_KEYS = ("april_tag_number_horizontal", "april_tag_number_vertical", "april_tag_size_m",
                  "april_tag_gap_size_m")
_HAND_EYE_BORDER_KEY = "april_tag_number_pixel_boarder"  # sic


@dataclass(frozen=True)
class KalibrCheckerboard:
    """A Kalibr checkerboard target (``target_type: checkerboard``).

    Attributes
    ----------
    target_cols, target_rows : int
        INNER corners along a row and along a column (Kalibr ``targetCols``, ``targetRows``).
    row_spacing_m, col_spacing_m : float
        Square sizes, metres (Kalibr ``rowSpacingMeters``, ``colSpacingMeters``).
    """

    target_cols: int
    target_rows: int
    row_spacing_m: float
    col_spacing_m: float

    def config(self) -> dict:
        """The cvsflow ``board`` block of this checkerboard (squares = inner corners + 1).

        Returns
        -------
        board : dict
            ``squares_x = target_cols + 1``, ``squares_y = target_rows + 1``,
            ``square_m = row_spacing_m`` (OpenCV's pattern size is ``(target_cols,
            target_rows)`` in both tools).

        Raises
        ------
        ConfigError
            The squares are not square (a cvsflow board has one ``square_m``).
        """
        if not math.isclose(self.row_spacing_m, self.col_spacing_m, rel_tol=1e-9):
            raise ConfigError(
                f"Kalibr checkerboard: rowSpacingMeters={self.row_spacing_m} differs from "
                f"colSpacingMeters={self.col_spacing_m}; cvsflow's chessboards have square squares "
                "(one square_m)"
            )
        return {"squares_x": self.target_cols + 1, "squares_y": self.target_rows + 1,
                "square_m": self.row_spacing_m}


def kalibr_target(data: Mapping, source: str) -> AprilGrid | KalibrCheckerboard:
    """The target a Kalibr target file describes.

    Parameters
    ----------
    data : Mapping
        The file's parsed YAML: Kalibr's top-level keys, yac's ``calib_target`` block or ETH
        hand_eye_calibration's keys (see the module notes).
    source : str
        The file's name, for messages.

    Returns
    -------
    target : AprilGrid or KalibrCheckerboard

    Raises
    ------
    ConfigError
        ``target_type`` missing or not ``aprilgrid``/``checkerboard`` (Kalibr's ``circlegrid``
        included), or a key missing or invalid; the message names the file, the key, its value
        and what was expected.
    """
    where = str(source)
    if not isinstance(data, Mapping):
        raise ConfigError(f"{where}: expected a mapping of target keys, got {type(data).__name__}")
    if "target_type" not in data and isinstance(data.get("calib_target"), Mapping):
        data, where = data["calib_target"], f"{source}: calib_target"
    if "target_type" not in data:
        if all(key in data for key in _HAND_EYE_KEYS[:2]):
            return _hand_eye_aprilgrid(data, where)
        raise ConfigError(f"{where}: missing key 'target_type' (expected 'aprilgrid' or 'checkerboard')")
    target_type = data["target_type"]
    if target_type == "aprilgrid":
        keys = _YAC_APRILGRID_KEYS if _YAC_APRILGRID_KEYS[0] in data else _KALIBR_APRILGRID_KEYS
        cols, rows, size, spacing = (_value(data, key, where) for key in keys)
        _check_int(cols, keys[0], where, minimum=1)
        _check_int(rows, keys[1], where, minimum=1)
        _check_length(size, keys[2], where)
        _check_number(spacing, keys[3], where)
        if not 0.0 < spacing <= 1.0:
            raise ConfigError(
                f"{where}: {keys[3]}={spacing!r}; expected the gap as a ratio of the tag size in "
                "(0, 1] (e.g. 0.3), not a gap in metres"
            )
        return _grid(where, tag_cols=cols, tag_rows=rows, tag_size_m=float(size), tag_spacing=float(spacing))
    if target_type == "checkerboard":
        cols, rows, row_m, col_m = (_value(data, key, where) for key in _KALIBR_CHECKERBOARD_KEYS)
        _check_int(cols, "targetCols", where, minimum=2)
        _check_int(rows, "targetRows", where, minimum=2)
        _check_length(row_m, "rowSpacingMeters", where)
        _check_length(col_m, "colSpacingMeters", where)
        return KalibrCheckerboard(cols, rows, float(row_m), float(col_m))
    raise ConfigError(
        f"{where}: target_type={target_type!r} is not supported; expected one of "
        f"{list(KALIBR_TARGET_TYPES)} (cvsflow has no circle-grid board)"
    )


def kalibr_board(data: Mapping, source: str) -> dict:
    """The cvsflow ``board`` block of a Kalibr target file's content.

    Parameters
    ----------
    data : Mapping
        The file's parsed YAML (:func:`kalibr_target`).
    source : str
        The file's name, for messages.

    Returns
    -------
    board : dict
        ``{type: aprilgrid, tag_cols, tag_rows, tag_size_m, tag_spacing}`` for an AprilGrid,
        ``{squares_x, squares_y, square_m}`` for a checkerboard.

    Raises
    ------
    ConfigError
        As :func:`kalibr_target`, and a checkerboard whose squares are not square.
    """
    target = kalibr_target(data, source)
    try:
        return target.config()
    except ConfigError as exc:
        raise ConfigError(f"{source}: {exc}") from exc


def _hand_eye_aprilgrid(data: Mapping, where: str) -> AprilGrid:
    cols, rows, size, gap = (_value(data, key, where) for key in _HAND_EYE_KEYS)
    border = data.get(_HAND_EYE_BORDER_KEY, KALIBR_BORDER_BITS)
    _check_int(cols, _HAND_EYE_KEYS[0], where, minimum=1)
    _check_int(rows, _HAND_EYE_KEYS[1], where, minimum=1)
    _check_length(size, _HAND_EYE_KEYS[2], where)
    _check_length(gap, _HAND_EYE_KEYS[3], where)
    _check_int(border, _HAND_EYE_BORDER_KEY, where, minimum=1)
    spacing = float(gap) / float(size)
    if spacing > 1.0:
        raise ConfigError(f"{where}: {_HAND_EYE_KEYS[3]}={gap!r} is larger than {_HAND_EYE_KEYS[2]}={size!r}")
    return _grid(where, tag_cols=cols, tag_rows=rows, tag_size_m=float(size), tag_spacing=spacing,
                 border_bits=border)


def _grid(where: str, **kwargs) -> AprilGrid:
    try:
        return AprilGrid(**kwargs)
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from exc


def _value(data: Mapping, key: str, where: str):
    if key not in data:
        raise ConfigError(f"{where}: missing key {key!r}")
    return data[key]


def _check_number(value, key: str, where: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ConfigError(f"{where}: {key}={value!r}; expected a number")


def _check_length(value, key: str, where: str) -> None:
    _check_number(value, key, where)
    if not value > 0.0:
        raise ConfigError(f"{where}: {key}={value!r}; expected a length > 0 m")


def _check_int(value, key: str, where: str, minimum: int) -> None:
    if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
        raise ConfigError(f"{where}: {key}={value!r}; expected an integer >= {minimum}")
