"""TUM RGB-D trajectories: ``t x y z qx qy qz qw`` per line, whitespace separated, seconds.

``#`` lines are comments (the benchmark's files start with three). The quaternion is Hamilton,
scalar last; positions in metres.
"""

from __future__ import annotations

import pandas as pd

from cvsflow.io.mocap.markers import FileHead
from cvsflow.io.mocap.stream_layout import looks_ns, stream_layout
from cvsflow.io.mocap.streams import QUAT_NORM_TOL, pose_stream_format, read_positional

KEY = "tum"
TITLE = "TUM trajectory (whitespace-separated 't x y z qx qy qz qw', seconds)"


def detect(head: FileHead) -> str | None:
    """Why the file is a TUM trajectory (whitespace-separated rows of 8 numbers), or None.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None
    """
    lay = stream_layout(head)
    if lay.separator == "whitespace" and lay.n_fields == 8 and not looks_ns(lay.first_time):
        return "whitespace-separated rows of 8 numbers"
    return None


def _reject(lay) -> str | None:
    return f"line {lay.first_data_line} is comma separated" if lay.separator == "," else None


def read_stream(path, *, in_time_order: bool = True, quat_tol: float = QUAT_NORM_TOL) -> pd.DataFrame:
    """The stream table of a TUM trajectory.

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
        Comma-separated rows, rows of another length or times of ns (the line named).
    QuaternionNormError, TimestampOrderError
        :func:`cvsflow.io.mocap.streams.stream_table`.
    """
    return read_positional(path, KEY, TITLE, _reject, in_time_order=in_time_order, quat_tol=quat_tol)


FORMAT = pose_stream_format(KEY, TITLE, detect, read_stream)
