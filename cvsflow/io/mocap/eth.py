"""ETH ASL hand_eye_calibration pose CSVs: ``t, x, y, z, qx, qy, qz, qw`` per line, seconds.

Written by that toolbox's bag extractors and target extractor (Furrer et al. 2017): comma
separated (white space accepted when the format is named), time in seconds, positions in
metres, Hamilton quaternions scalar last, optionally one header line. Its target extractor's
header ``timestamp, x [m], y[m], z[m], x, y, z, w`` repeats names, so the columns are taken by
position, never by name. In that toolbox's naming a ``*_W_<camera>.csv`` file is ``T_W_E``, the
camera E in the *target* frame W, which is cvsflow's ``T_B_C``; a Vicon or robot file
``T_B_H`` is cvsflow's ``T_W_Cm``.
"""

from __future__ import annotations

import pandas as pd

from cvsflow.io.mocap.markers import FileHead
from cvsflow.io.mocap.stream_layout import looks_ns, stream_layout
from cvsflow.io.mocap.streams import QUAT_NORM_TOL, pose_stream_format, read_positional

KEY = "eth"
TITLE = "ETH hand_eye_calibration CSV (comma-separated 't, x, y, z, qx, qy, qz, qw', seconds)"


def _asl_header(lay) -> str | None:
    """Why the header makes the file an ASL CSV (names in another order, units, '#'), or None."""
    if lay.header is not None and lay.names_all_roles and (not lay.positional or lay.units or lay.hashed):
        return (f"line {lay.header_line} is a header naming the columns in another order or with "
                "units (an ASL CSV)")  # fmt: skip
    return None


def detect(head: FileHead) -> str | None:
    """Why the file is an ETH pose CSV, or None.

    Rows of 8 numbers with the time in seconds, comma separated (or white space, which a TUM
    file shares: auto detection tries TUM first), with no header or one that does not name the
    columns in another order or with units.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None
    """
    lay = stream_layout(head)
    if lay.n_fields != 8 or looks_ns(lay.first_time) or _asl_header(lay):
        return None
    sep = "comma" if lay.separator == "," else "whitespace"
    return f"{sep}-separated rows of 8 numbers, time in seconds"


def read_stream(path, *, in_time_order: bool = True, quat_tol: float = QUAT_NORM_TOL) -> pd.DataFrame:
    """The stream table of an ETH pose CSV.

    Parameters
    ----------
    path : str or Path
    in_time_order : bool
        The time-order policy of :mod:`cvsflow.io.mocap.streams` (False: file order).
    quat_tol : float
        Largest accepted | |q| - 1 |.

    Returns
    -------
    DataFrame
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS`.

    Raises
    ------
    PoseFormatError
        Rows of another length, times of ns, a header naming the columns in another order or
        with units (an ASL file); a bad row (line named).
    QuaternionNormError, TimestampOrderError
        :func:`cvsflow.io.mocap.streams.stream_table`.
    """
    return read_positional(path, KEY, TITLE, _asl_header, in_time_order=in_time_order, quat_tol=quat_tol)


FORMAT = pose_stream_format(KEY, TITLE, detect, read_stream)
