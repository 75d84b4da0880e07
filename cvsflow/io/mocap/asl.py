"""ASL / EuRoC / Kalibr pose CSVs: a header naming the columns, times in integer nanoseconds.

Examples::

    #timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z [],...
    timestamp [ns],x,y,z,qx,qy,qz,qw

The columns are found by name (:func:`cvsflow.io.mocap.streams.header_roles`), in whatever order
the header gives, with extra columns allowed and listed (EuRoC's velocities and biases). Time is
in ns unless the header says ``[s]``, ``[ms]`` or ``[us]``; position in metres unless ``[mm]`` or
``[cm]``. Quaternions are Hamilton (scalar ``q_*_w`` found by name, whatever its column).
"""

from __future__ import annotations

import re
from pathlib import Path

import pandas as pd

from cvsflow.exceptions import MissingColumnError, PoseFormatError
from cvsflow.io.mocap.markers import FileHead, read_head
from cvsflow.io.mocap.stream_layout import ROLES, looks_ns, stream_layout
from cvsflow.io.mocap.streams import (
    NS_PER,
    POS_SCALE,
    QUAT_NORM_TOL,
    pose_stream_format,
    read_rows,
    stream_table,
)

KEY = "asl"
TITLE = "ASL/EuRoC pose CSV (a header naming the columns, times in ns)"


def detect(head: FileHead) -> str | None:
    """Why the file is an ASL pose CSV, or None.

    A comma-separated file whose header line names a time column and most of x, y, z, qx, qy,
    qz, qw (so that a missing one is named by :func:`read_stream`), unless the header is
    ETH's positional ``t x y z qx qy qz qw`` in seconds (no units, no ``#``, no ns integers).

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None
    """
    lay = stream_layout(head)
    if lay.separator != "," or lay.header is None or "t" not in lay.roles or lay.ambiguous:
        return None
    if len(lay.missing) > 3:
        return None
    if lay.positional and not lay.units and not lay.hashed and not looks_ns(lay.first_time):
        return None  # ETH's header: positional, seconds
    return "a header names the columns: " + ", ".join(lay.header)


def read_stream(path, *, in_time_order: bool = True, quat_tol: float = QUAT_NORM_TOL) -> pd.DataFrame:
    """The stream table of an ASL pose CSV.

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
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS`; ``attrs["columns"]`` (role -> header
        name) and ``attrs["ignored_columns"]``.

    Raises
    ------
    PoseFormatError
        No header naming the columns, whitespace-separated rows, a time that is not an integer
        of ns (unless the header gives another unit), an unknown unit; a bad row (line named).
    MissingColumnError
        A role no header name matches, or that several match (line and names given).
    QuaternionNormError, TimestampOrderError
        :func:`cvsflow.io.mocap.streams.stream_table`.
    """
    path = Path(path)
    lay = stream_layout(read_head(path))
    if lay.first_data_line is None:
        raise PoseFormatError(f"{path}: no row of numbers; expected an {TITLE}")
    if lay.separator != ",":
        raise PoseFormatError(f"{path}: not an {TITLE}: the rows are whitespace separated")
    if lay.header is None:
        raise PoseFormatError(f"{path}: not an {TITLE}: no header line names the columns "
                              f"(line {lay.first_data_line} is the first row of numbers)")  # fmt: skip
    if lay.ambiguous:
        raise MissingColumnError(
            f"{path}, line {lay.header_line}: the header names several columns for "
            + "; ".join(f"{r}: {v}" for r, v in lay.ambiguous.items())
            + "; expected one column per role (ETH's extractor header repeats x, y, z: read that "
            "file with format eth)"
        )
    if lay.missing:
        raise MissingColumnError(
            f"{path}, line {lay.header_line}: no column for {lay.missing} in the header "
            f"{lay.header}; expected a time (timestamp [ns]), a position (x y z, p_*_x ...) and a "
            "quaternion (qx qy qz qw, q_*_x ...)"
        )
    unit = lay.units.get("t", "ns")
    if unit not in NS_PER:
        raise PoseFormatError(f"{path}, line {lay.header_line}: time unit [{unit}] of "
                              f"{lay.header[lay.roles['t']]!r}; expected one of {list(NS_PER)}")  # fmt: skip
    first_t = lay.first_time
    if unit == "ns" and not re.fullmatch(r"[+-]?\d+", first_t):
        raise PoseFormatError(f"{path}, line {lay.first_data_line}: time {first_t!r} is not an "
                              "integer of ns; expected integer nanoseconds, or a unit in the "
                              "header (timestamp [s])")  # fmt: skip
    pos_unit = lay.units.get("x", "m")
    if pos_unit not in POS_SCALE:
        raise PoseFormatError(f"{path}, line {lay.header_line}: position unit [{pos_unit}]; "
                              f"expected one of {list(POS_SCALE)}")  # fmt: skip
    cols = [lay.roles[r] for r in ROLES]
    names = {r: lay.header[lay.roles[r]] for r in ROLES}
    t_ns, values, line = read_rows(path, lay, cols, unit, ", ".join(lay.header))
    return stream_table(
        path, KEY, t_ns, values, line, time_unit=unit, position_scale=POS_SCALE[pos_unit],
        quat_names=[names[r] for r in ("qx", "qy", "qz", "qw")], quat_tol=quat_tol,
        in_time_order=in_time_order,
        attrs={"columns": names, "ignored_columns": [n for i, n in enumerate(lay.header) if i not in cols]},
    )  # fmt: skip


FORMAT = pose_stream_format(KEY, TITLE, detect, read_stream)
