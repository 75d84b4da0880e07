"""Calibration target files: a Kalibr target YAML read into a cvsflow board.

The format and its spellings are :mod:`cvsflow.board.kalibr`'s; this module reads the file.
"""

from __future__ import annotations

from pathlib import Path

from cvsflow.board import AprilGrid, KalibrCheckerboard, kalibr_board, kalibr_target
from cvsflow.io.files import read_yaml


def read_kalibr_target(path) -> AprilGrid | KalibrCheckerboard:
    """The target of a Kalibr target file (``target_type: aprilgrid | checkerboard``).

    Parameters
    ----------
    path : str or Path
        The YAML file.

    Returns
    -------
    target : AprilGrid or KalibrCheckerboard

    Raises
    ------
    InputError
        The file is missing, not YAML or not a mapping.
    ConfigError
        An unsupported ``target_type`` or a missing or invalid key (the file and key named).
    """
    return kalibr_target(read_yaml(path), str(path))


def read_target_board(path) -> dict:
    """The cvsflow ``board`` block of a Kalibr target file.

    Parameters
    ----------
    path : str or Path
        The YAML file.

    Returns
    -------
    board : dict
        ``{type: aprilgrid, tag_cols, tag_rows, tag_size_m, tag_spacing}`` or, for a Kalibr
        checkerboard, ``{squares_x, squares_y, square_m}`` (squares = inner corners + 1).

    Raises
    ------
    InputError
        The file is missing, not YAML or not a mapping.
    ConfigError
        As :func:`read_kalibr_target`, and a checkerboard whose squares are not square.
    """
    return kalibr_board(read_yaml(Path(path)), str(path))
