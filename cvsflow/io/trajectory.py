"""Trajectory files with exact int64 nanosecond times: TUM, EuRoC/ASL CSV and KITTI (+ times).

One parser per format: TUM and ASL/EuRoC files are read by the pose-stream readers of
:mod:`cvsflow.io.mocap` (:mod:`~cvsflow.io.mocap.tum`, :mod:`~cvsflow.io.mocap.asl`); this
module adds KITTI's reader, the three writers, and :func:`read_trajectory` /
:func:`write_trajectory`, which dispatch on a declared format (:data:`FORMATS`).

Readers return the stream table of :mod:`cvsflow.io.mocap.streams` (``t_ns`` int64 exact,
``t_s``, ``x_m y_m z_m``, ``qx qy qz qw`` scalar-last, ``line``). Writers take any table with
``x_m .. qw`` and either ``t_ns`` (int64, written as is) or only ``t_s`` (float seconds: the
nearest nanosecond of the float's exact value is written); rows whose ``pos_valid`` or
``rot_valid`` is False are left out (no format has a validity flag). Pose values are written
with the shortest text that reads back to the same float, so TUM and ASL files round-trip
bit-exact; times are written from the integer, never through a float.

=========  ===========================================================================  ===========
format     file                                                                         times
=========  ===========================================================================  ===========
``tum``    ``t x y z qx qy qz qw``, one space apart (evo's reader splits on one space)  s, 9 decimals
``asl``    EuRoC's header ``#timestamp [ns],p_RS_R_x [m],...,q_RS_w [],q_RS_x [],...``  integer ns
           (quaternion scalar FIRST, as EuRoC and ``evo_ape euroc`` have it)
``kitti``  12 numbers per line, ``[R | t]`` row-major; no times in the file: a times   s, 9 decimals
           file beside it, one time per line (:func:`kitti_times_path`)
=========  ===========================================================================  ===========

KITTI stores a rotation matrix, so its quaternions round-trip to ~1e-16, not bit-exact.
"""

from __future__ import annotations

from decimal import ROUND_HALF_EVEN, Decimal
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError, PoseFormatError
from cvsflow.geometry import R_from_quat, quat_from_R
from cvsflow.io.files import atomic_output
from cvsflow.io.mocap import asl, tum
from cvsflow.io.mocap.streams import stream_table, time_to_ns

#: Declared trajectory formats.
FORMATS = ("tum", "asl", "kitti")
#: File suffix of each format (KITTI's times file: :func:`kitti_times_path`).
SUFFIX = {"tum": ".tum", "asl": ".csv", "kitti": ".kitti"}
#: EuRoC's ground-truth header (the pose columns of ``state_groundtruth_estimate0/data.csv``).
ASL_HEADER = ("#timestamp [ns],p_RS_R_x [m],p_RS_R_y [m],p_RS_R_z [m],"
              "q_RS_w [],q_RS_x [],q_RS_y [],q_RS_z []")  # fmt: skip
POSE_COLS = ["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]
NS_PER_S = 10**9
#: Largest |R^T R - I| of a KITTI matrix read as a rotation (files written with 6 digits reach 1e-6).
ROTATION_TOL = 1e-3


def seconds_text(t_ns: int) -> str:
    """A time in nanoseconds as seconds with exactly 9 decimals, from the integer.

    Parameters
    ----------
    t_ns : int
        Nanoseconds, any sign.

    Returns
    -------
    str
        E.g. ``"1606153863.362296104"``; ``"-0.000000001"`` for -1.
    """
    t_ns = int(t_ns)
    s, ns = divmod(abs(t_ns), NS_PER_S)
    return f"{'-' if t_ns < 0 else ''}{s}.{ns:09d}"


def table_ns(df: pd.DataFrame) -> np.ndarray:
    """The exact times of a trajectory table, nanoseconds.

    Parameters
    ----------
    df : DataFrame
        With ``t_ns`` (integer) or ``t_s`` (float seconds).

    Returns
    -------
    ndarray of int64, shape (N,)
        ``t_ns`` as is; else the nearest nanosecond of each ``t_s``'s exact binary value
        (ties to even), what ``f"{t_s:.9f}"`` prints.

    Raises
    ------
    ValueError
        Neither column, a ``t_ns`` that is not integer, or a ``t_s`` that is not finite.
    """
    if "t_ns" in df.columns:
        if not pd.api.types.is_integer_dtype(df["t_ns"]):
            raise ValueError(f"t_ns must be integer nanoseconds, not {df['t_ns'].dtype}")
        return df["t_ns"].to_numpy(np.int64)
    if "t_s" not in df.columns:
        raise ValueError(f"a trajectory table needs t_ns or t_s; it has {list(df.columns)}")
    t_s = df["t_s"].to_numpy(float)
    if not np.isfinite(t_s).all():
        raise ValueError(f"t_s row {int(np.flatnonzero(~np.isfinite(t_s))[0])} is not finite")
    scale = Decimal(NS_PER_S)
    return np.array([int((Decimal(x) * scale).to_integral_value(ROUND_HALF_EVEN)) for x in t_s.tolist()],
                    dtype=np.int64)  # fmt: skip


def _rows(df: pd.DataFrame, only_valid: bool, path) -> tuple[list[int], list[list[float]]]:
    """Times (ns) and pose values of the rows to write; NaN in a row to write is an error."""
    missing = [c for c in POSE_COLS if c not in df.columns]
    if missing:
        raise ValueError(f"{path}: the table lacks {missing} (expected x_m y_m z_m qx qy qz qw)")
    keep = np.ones(len(df), bool)
    if only_valid:
        for flag in ("pos_valid", "rot_valid"):
            if flag in df.columns:
                keep &= df[flag].to_numpy(bool)
    t = table_ns(df)[keep]
    v = df[POSE_COLS].to_numpy(float)[keep]
    bad = ~np.isfinite(v).all(axis=1)
    if bad.any():
        raise ValueError(f"{path}: {int(bad.sum())} rows to write have a NaN or infinite pose (first: "
                         f"row {int(np.flatnonzero(keep)[np.flatnonzero(bad)[0]])}); no format has a "
                         "validity flag: mark them pos_valid/rot_valid False")  # fmt: skip
    return t.tolist(), v.tolist()


def _write_lines(path, lines) -> None:
    """Write text lines atomically, LF endings."""
    with atomic_output(path) as tmp, open(tmp, "w", newline="\n") as fh:
        fh.writelines(line + "\n" for line in lines)


def write_tum(df: pd.DataFrame, path, only_valid: bool = True) -> None:
    """Write a TUM trajectory (``t x y z qx qy qz qw``, seconds), atomically.

    Parameters
    ----------
    df : DataFrame
        ``t_ns`` or ``t_s``; ``x_m .. qw`` (m, scalar-last quaternion).
    path : str or Path
        Output file; ``evo_ape tum`` reads it.
    only_valid : bool
        Leave out rows whose ``pos_valid`` or ``rot_valid`` is False.

    Returns
    -------
    None
        A ``#`` header line, then one line per row (times with 9 decimals from the integer ns).

    Raises
    ------
    ValueError
        A missing column, or a NaN pose among the rows to write.
    """
    t, v = _rows(df, only_valid, path)
    header = "# timestamp tx ty tz qx qy qz qw (s, m, scalar-last quaternion)"
    _write_lines(path, [header] + [" ".join([seconds_text(tn), *map(repr, row)]) for tn, row in
                                   zip(t, v, strict=True)])  # fmt: skip


def write_asl(df: pd.DataFrame, path, only_valid: bool = True) -> None:
    """Write an EuRoC/ASL pose CSV (integer ns; quaternion scalar first), atomically.

    Parameters
    ----------
    df : DataFrame
        ``t_ns`` or ``t_s``; ``x_m .. qw`` (m, scalar-last quaternion).
    path : str or Path
        Output file; ``evo_ape euroc`` and :func:`cvsflow.io.mocap.asl.read_stream` read it.
    only_valid : bool
        Leave out rows whose ``pos_valid`` or ``rot_valid`` is False.

    Returns
    -------
    None
        :data:`ASL_HEADER`, then ``t_ns,x,y,z,qw,qx,qy,qz`` per row.

    Raises
    ------
    ValueError
        A missing column, or a NaN pose among the rows to write.
    """
    t, v = _rows(df, only_valid, path)
    _write_lines(path, [ASL_HEADER] + [",".join([str(tn), *map(repr, row[:3] + row[6:] + row[3:6])])
                                       for tn, row in zip(t, v, strict=True)])  # fmt: skip


def kitti_times_path(path) -> Path:
    """The times file written beside a KITTI poses file: ``<stem>.times.txt``.

    Parameters
    ----------
    path : str or Path
        The poses file.

    Returns
    -------
    Path
    """
    path = Path(path)
    return path.with_name(f"{path.stem}.times.txt")


def write_kitti(df: pd.DataFrame, path, times_path=None, only_valid: bool = True) -> None:
    """Write a KITTI poses file (3x4 ``[R | t]`` row-major) and its times file, atomically.

    Parameters
    ----------
    df : DataFrame
        ``t_ns`` or ``t_s``; ``x_m .. qw`` (m, scalar-last quaternion, turned into R).
    path : str or Path
        The poses file (``evo_ape kitti`` reads it).
    times_path : str or Path, optional
        One time per line, seconds with 9 decimals; default :func:`kitti_times_path`.
    only_valid : bool
        Leave out rows whose ``pos_valid`` or ``rot_valid`` is False.

    Returns
    -------
    None

    Raises
    ------
    ValueError
        A missing column, or a NaN pose among the rows to write.
    """
    t, v = _rows(df, only_valid, path)
    a = np.asarray(v, float).reshape(-1, 7)
    M = np.concatenate([R_from_quat(a[:, 3:]).reshape(-1, 3, 3), a[:, :3, None]], axis=2).reshape(-1, 12)
    _write_lines(path, [" ".join(map(repr, row)) for row in M.tolist()])
    _write_lines(times_path or kitti_times_path(path), [seconds_text(tn) for tn in t])


def _read_numbers(path, n: int, what: str):
    """Rows of ``n`` whitespace-separated fields (texts) and their line numbers; ``#`` comments."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found (expected {what})")
    rows, lines = [], []
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            s = raw.strip()
            if not s or s.startswith("#"):
                continue
            fields = s.split()
            if len(fields) != n:
                raise PoseFormatError(f"{path}, line {lineno}: {len(fields)} fields; expected {n} ({what})")
            rows.append(fields)
            lines.append(lineno)
    if not rows:
        raise PoseFormatError(f"{path}: no data line (expected {what})")
    return rows, np.asarray(lines, np.int64)


def read_kitti(path, times_path=None, *, in_time_order: bool = True) -> pd.DataFrame:
    """A KITTI poses file and its times file as a stream table.

    Parameters
    ----------
    path : str or Path
        12 numbers per line, the 3x4 ``[R | t]`` row-major (m).
    times_path : str or Path, optional
        One time per line, seconds (decimal text, read exactly); as many as poses. Default
        :func:`kitti_times_path`.
    in_time_order : bool
        The time-order policy of :mod:`cvsflow.io.mocap.streams` (False: file order).

    Returns
    -------
    DataFrame
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS` (``line``: the poses file's);
        quaternions from the matrices (qw >= 0); ``attrs["times_path"]``,
        ``attrs["max_orthonormality_error"]``.

    Raises
    ------
    InputError
        A missing file (KITTI poses carry no times: the times file is needed).
    PoseFormatError
        A line of another length or not numbers, a matrix that is not a rotation (line named),
        a times file of another length.
    TimestampOrderError
        :func:`cvsflow.io.mocap.streams.stream_table`.
    """
    path = Path(path)
    times_path = Path(times_path) if times_path is not None else kitti_times_path(path)
    rows, line = _read_numbers(path, 12, "the 3x4 pose matrix [R | t], row-major")
    try:
        M = np.asarray(rows, float).reshape(-1, 3, 4)
    except ValueError as exc:
        raise PoseFormatError(f"{path}: not a number ({exc}); expected 12 numbers per line") from None
    if not times_path.is_file():
        raise InputError(f"{times_path}: file not found (KITTI poses carry no times: expected the "
                         f"times file of {path.name}, one time in seconds per line)")  # fmt: skip
    times, t_line = _read_numbers(times_path, 1, "one time in seconds")
    if len(times) != len(M):
        raise PoseFormatError(f"{times_path}: {len(times)} times for the {len(M)} poses of {path}")
    try:
        t_ns = np.array([time_to_ns(f[0], "s") for f in times], np.int64)
    except ValueError as exc:
        raise PoseFormatError(f"{times_path}: {exc}; expected one time in seconds per line") from None
    R = M[:, :, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    if not (err <= ROTATION_TOL).all():
        k = int(np.flatnonzero(~(err <= ROTATION_TOL))[0])
        raise PoseFormatError(f"{path}, line {line[k]}: the 3x3 part is not a rotation (|R^T R - I| = "
                              f"{err[k]:.3g} > {ROTATION_TOL:g})")  # fmt: skip
    values = np.concatenate([M[:, :, 3], quat_from_R(R).reshape(-1, 4)], axis=1)
    return stream_table(path, "kitti", t_ns, values, line, time_unit="s", in_time_order=in_time_order,
                        attrs={"times_path": str(times_path), "max_orthonormality_error": float(err.max())})


def read_trajectory(path, fmt: str, times_path=None, *, in_time_order: bool = True) -> pd.DataFrame:
    """A trajectory file of a declared format as a stream table (exact ``t_ns``).

    Parameters
    ----------
    path : str or Path
    fmt : {"tum", "asl", "kitti"}
        :data:`FORMATS`.
    times_path : str or Path, optional
        KITTI's times file (default :func:`kitti_times_path`).
    in_time_order : bool
        The time-order policy of :mod:`cvsflow.io.mocap.streams` (False: file order).

    Returns
    -------
    DataFrame
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS`.

    Raises
    ------
    InputError
        An unknown format; the format reader's named errors.
    """
    if fmt == "tum":
        return tum.read_stream(path, in_time_order=in_time_order)
    if fmt == "asl":
        return asl.read_stream(path, in_time_order=in_time_order)
    if fmt == "kitti":
        return read_kitti(path, times_path, in_time_order=in_time_order)
    raise InputError(f"{path}: trajectory format {fmt!r}; expected one of {list(FORMATS)}")


def write_trajectory(df: pd.DataFrame, path, fmt: str, times_path=None, only_valid: bool = True) -> None:
    """Write a trajectory table in a declared format (see the module docstring), atomically.

    Parameters
    ----------
    df : DataFrame
        ``t_ns`` or ``t_s``; ``x_m .. qw``.
    path : str or Path
    fmt : {"tum", "asl", "kitti"}
        :data:`FORMATS`.
    times_path : str or Path, optional
        KITTI's times file (default :func:`kitti_times_path`).
    only_valid : bool
        Leave out rows whose ``pos_valid`` or ``rot_valid`` is False.

    Returns
    -------
    None

    Raises
    ------
    ValueError
        An unknown format; a missing column or a NaN pose among the rows to write.
    """
    if fmt == "tum":
        write_tum(df, path, only_valid)
    elif fmt == "asl":
        write_asl(df, path, only_valid)
    elif fmt == "kitti":
        write_kitti(df, path, times_path, only_valid)
    else:
        raise ValueError(f"trajectory format {fmt!r}; expected one of {list(FORMATS)}")
