"""Time-stamped pose streams (one body's pose per row): exact times, the layout, the checks.

The pose-stream formats (:mod:`cvsflow.io.mocap.asl`, :mod:`~cvsflow.io.mocap.tum`,
:mod:`~cvsflow.io.mocap.eth`) parse their own columns and hand the rows to
:func:`stream_table`, which makes the *stream table*, one row per pose, in time order:

=================  ===========================================================================
``t_ns``           int64, the file's time in nanoseconds, exact: integers as written, decimal
                   seconds converted with integer arithmetic (:func:`time_to_ns`)
``t_s``            float64, ``t_ns / 1e9`` correctly rounded (:func:`seconds_from_ns`: the float a
                   reader of the decimal text gets; absolute Unix seconds keep only ~0.2 us in a
                   float: do time arithmetic on ``t_ns``)
``x_m y_m z_m``    position of the body in the stream's world, metres
``qx qy qz qw``    unit quaternion, scalar last (renormalised; the file's sign kept: streams
                   flip sign between rows, so never difference or average components)
``line``           int64, the row's line number in the file (1-based), for messages
=================  ===========================================================================

A row's pose is ``T_A_X``: body X in the stream's world A (which frames these are depends on the
source: a Vicon body in the Vicon world, a camera in a target's frame, ...).

Time order policy: a timestamp earlier than the row before it is an error
(:class:`~cvsflow.exceptions.TimestampOrderError`, both lines named): rows out of order are two
streams merged or a clock reset, which no reader should hide. Rows repeating the timestamp
before them (a Vicon stamped at 10 ms resolution writes some) keep the first: the others are
dropped with a WARNING naming the first pair of lines, their count and how far their poses
differ, and counted in ``attrs["n_duplicates_dropped"]``. A pose *list* (one pose per still,
paired by position) keeps the file's order and every row (``in_time_order=False``).
"""

from __future__ import annotations

import logging
import re
from decimal import ROUND_HALF_EVEN, Decimal, InvalidOperation
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.exceptions import PoseFormatError, PoseStreamError, QuaternionNormError, TimestampOrderError
from cvsflow.geometry import R_from_quat, make_T, rotation_angle
from cvsflow.io.mocap.markers import MocapExport, MocapFormat, marker_table, read_head
from cvsflow.io.mocap.stream_layout import StreamLayout, looks_ns, split_fields, stream_layout
from cvsflow.mocap import bodies_from_poses

log = logging.getLogger(__name__)

STREAM_COLUMNS = ["t_ns", "t_s", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw", "line"]
#: Largest | |q| - 1 | accepted (rows within it are renormalised): files written with 4 digits
#: reach 2e-4.
QUAT_NORM_TOL = 1e-3
NS_PER = {"s": 10**9, "ms": 10**6, "us": 10**3, "ns": 1}
POS_SCALE = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}

_PLAIN_DECIMAL = re.compile(r"([+-]?)(\d+)(?:\.(\d*))?")


def time_to_ns(text: str, unit: str) -> int:
    """A time as written, in ``unit``, to integer nanoseconds by exact decimal arithmetic.

    Parameters
    ----------
    text : str
        E.g. ``"1491754391.84618"``, ``"1606153863362296104"``, ``"1.4917e9"``.
    unit : {"s", "ms", "us", "ns"}
        The unit the text is in.

    Returns
    -------
    int
        Nanoseconds; digits below 1 ns rounded half to even. ``float(text) * 1e9`` would give
        another number for Unix seconds with 7 decimals (float64 holds ~0.2 us there).

    Raises
    ------
    ValueError
        Not a finite decimal number.
    """
    scale = NS_PER[unit]
    m = _PLAIN_DECIMAL.fullmatch(text)
    if m is not None:
        sign, whole, frac = m.group(1), m.group(2), m.group(3) or ""
        digits = len(str(scale)) - 1  # decimals that are whole nanoseconds
        if len(frac) <= digits:
            v = int(whole) * scale + (int(frac.ljust(digits, "0")) if digits else 0)
            return -v if sign == "-" else v
    try:
        d = Decimal(text)
    except InvalidOperation:
        raise ValueError(f"{text!r} is not a number") from None
    if not d.is_finite():
        raise ValueError(f"{text!r} is not finite")
    return int((d * scale).quantize(Decimal(1), rounding=ROUND_HALF_EVEN))


def seconds_from_ns(t_ns) -> np.ndarray:
    """Seconds of exact nanosecond times, each the float nearest to ``t_ns / 1e9``.

    Parameters
    ----------
    t_ns : array_like of int, shape (N,)
        Nanoseconds.

    Returns
    -------
    ndarray of float64, shape (N,)
        What parsing ``"<s>.<9 digits>"`` gives (numpy, evo). ``t_ns / 1e9`` in numpy rounds
        twice (int64 to float64, then the division) and is one ulp off for some Unix times.
    """
    return np.array([n / 10**9 for n in np.asarray(t_ns, np.int64).tolist()], dtype=float)


def format_time(t_ns: int, unit: str) -> str:
    """A time for a message, in the file's unit (``1491754402.090000000 s`` or ``... ns``).

    Parameters
    ----------
    t_ns : int
        Time, ns.
    unit : str
        The file's time unit.

    Returns
    -------
    str
    """
    if unit == "ns":
        return f"{int(t_ns)} ns"
    s, ns = divmod(int(t_ns), 10**9)
    return f"{s}.{ns:09d} s"


# --------------------------------------------------------------------------- rows and the table


def read_rows(path, layout: StreamLayout, columns: list[int], time_unit: str, what: str):
    """Times (exact) and values of every data row of a stream file.

    Parameters
    ----------
    path : Path
        The file.
    layout : StreamLayout
        Its layout (separator, header line, field count).
    columns : list of int
        Field index of t, x, y, z, qx, qy, qz, qw.
    time_unit : {"s", "ms", "us", "ns"}
    what : str
        The expected row, for messages (``"t, x, y, z, qx, qy, qz, qw"``).

    Returns
    -------
    t_ns : ndarray of int64, shape (N,)
    values : ndarray, shape (N, 7)
        x, y, z (file units), qx, qy, qz, qw.
    line : ndarray of int64, shape (N,)
        1-based line numbers.

    Raises
    ------
    PoseFormatError
        A row with another number of fields, or a field that is not a number (line named);
        no data row at all. A last row the file ends inside (no line end: a file cut short) is
        left out with a WARNING, as a motion-capture take cut short is read as far as it goes.
    """
    t_ns, values, lines = [], [], []
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for lineno, raw in enumerate(fh, start=1):
            s = raw.strip()
            if not s or s.startswith("#") or lineno == layout.header_line:
                continue
            fields = split_fields(s, layout.separator)
            if len(fields) < layout.n_fields and not raw.endswith("\n") and lines:
                # the file ends inside this row (a copy or export interrupted): as a cut take
                log.warning("%s, line %d: the file ends inside this row (%d of %d fields): cut short; "
                            "the row is left out, the %d rows before it are read", path, lineno,
                            len(fields), layout.n_fields, len(lines))  # fmt: skip
                break
            if len(fields) != layout.n_fields:
                raise PoseFormatError(
                    f"{path}, line {lineno}: {len(fields)} fields; expected {layout.n_fields} ({what})"
                )
            try:
                t_ns.append(time_to_ns(fields[columns[0]], time_unit))
                values.append([float(fields[c]) for c in columns[1:]])
            except ValueError as exc:
                raise PoseFormatError(f"{path}, line {lineno}: not a number ({exc}); "
                                      f"expected {what}") from None  # fmt: skip
            lines.append(lineno)
    if not lines:
        raise PoseFormatError(f"{path}: no pose rows (expected rows of {what})")
    return np.asarray(t_ns, np.int64), np.asarray(values, float), np.asarray(lines, np.int64)


def _unit_quaternions(path, q, line, quat_tol, quat_names, row_word="line"):
    """Rows of q off unit norm by over 1e-12 renormalised (the others kept bit for bit, so a file
    written from unit quaternions reads back exactly); an error naming the first row off unit
    norm beyond quat_tol."""
    norm = np.linalg.norm(q, axis=1)
    bad = ~np.isfinite(norm) | (np.abs(norm - 1.0) > quat_tol)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise QuaternionNormError(
            f"{path}, {row_word} {line[k]}: quaternion ({', '.join(quat_names)}) = {q[k].tolist()} has "
            f"norm {norm[k]:.6g}, off 1 by more than {quat_tol:g} ({int(bad.sum())} rows so, the "
            "first named); expected a unit quaternion (qx qy qz qw)"
        )
    off = np.abs(norm - 1.0) > 1e-12
    q = np.where(off[:, None], q / norm[:, None], q)
    return q, int(off.sum()), float(np.max(np.abs(norm - 1.0)))


def _drop_repeated_stamps(path, t, p, q, line, time_unit, row_word="line"):
    """Keep the first row of each run of equal timestamps; a WARNING names the first pair."""
    same = np.diff(t) == 0
    if not same.any():
        return t, p, q, line, 0
    k = int(np.flatnonzero(same)[0])
    keep = np.concatenate([[True], ~same])
    rep = np.flatnonzero(~keep)
    prev = np.maximum.accumulate(np.where(keep, np.arange(len(t)), 0))[rep]  # first row of the run
    d_mm = 1e3 * np.linalg.norm(p[rep] - p[prev], axis=1)
    d_deg = np.degrees(rotation_angle(np.swapaxes(R_from_quat(q[prev]), 1, 2) @ R_from_quat(q[rep])))
    log.warning(
        "%s, %ss %d and %d: both at time %s; %d rows repeat the timestamp before them and are "
        "dropped (the first of each kept; their poses differ from it by up to %.3g mm, %.3g deg)",
        path, row_word, line[k], line[k + 1], format_time(t[k], time_unit), len(rep), d_mm.max(), d_deg.max(),
    )  # fmt: skip
    return t[keep], p[keep], q[keep], line[keep], len(rep)


def stream_table(path, fmt: str, t_ns, values, line, *, time_unit: str, position_scale: float = 1.0,
                 quat_names=("qx", "qy", "qz", "qw"), quat_tol: float = QUAT_NORM_TOL,
                 in_time_order: bool = True, attrs: dict | None = None,
                 row_word: str = "line") -> pd.DataFrame:  # fmt: skip
    """The stream table of parsed rows, after the quaternion and time-order checks.

    Parameters
    ----------
    path : Path
        The file (for messages and ``attrs``).
    fmt : str
        The format's key.
    t_ns : ndarray of int64, shape (N,)
        Exact times, ns.
    values : ndarray, shape (N, 7)
        x, y, z (file units), qx, qy, qz, qw (scalar last).
    line : ndarray of int64, shape (N,)
        Line numbers.
    time_unit : str
        The file's time unit (for messages).
    position_scale : float
        Metres per file unit of position.
    quat_names : sequence of str
        The file's names of the quaternion columns (for messages).
    quat_tol : float
        Largest accepted | |q| - 1 |.
    in_time_order : bool
        True (a stream): the time-order policy of the module docstring. False (a pose list):
        file order, every row kept.
    attrs : dict, optional
        More ``attrs`` (columns found, ignored columns, ...).
    row_word : str
        What ``line`` counts, in messages (``line`` in a file; ``message`` in a bag's topic).

    Returns
    -------
    stream : DataFrame
        :data:`STREAM_COLUMNS`; ``attrs``: ``path``, ``format``, ``time_unit``,
        ``n_rows_file``, ``n_duplicates_dropped``, ``n_quats_renormalised``,
        ``max_quat_norm_error`` and ``attrs``.

    Raises
    ------
    PoseStreamError
        A position that is not finite (line named).
    QuaternionNormError
        A quaternion off unit norm by more than ``quat_tol`` (first line named, with the count).
    TimestampOrderError
        A time earlier than the row before it (both lines named, with the count).
    """
    p = values[:, :3] * position_scale
    finite = np.isfinite(p).all(axis=1)
    if not finite.all():
        k = int(np.flatnonzero(~finite)[0])
        raise PoseStreamError(f"{path}, {row_word} {line[k]}: position {values[k, :3].tolist()} "
                              "is not finite")  # fmt: skip
    q, n_renorm, max_err = _unit_quaternions(path, values[:, 3:7], line, quat_tol, quat_names, row_word)
    t = np.asarray(t_ns, np.int64)
    n_rows = len(t)
    n_dup = 0
    if in_time_order:
        back = np.flatnonzero(np.diff(t) < 0)
        if len(back):
            k = int(back[0])
            raise TimestampOrderError(
                f"{path}, {row_word} {line[k + 1]}: time {format_time(t[k + 1], time_unit)} is earlier "
                f"than {row_word} {line[k]}'s {format_time(t[k], time_unit)} ({len(back)} such steps); "
                "expected the rows in time order (rows out of order are streams merged or a clock "
                "reset: fix the file's source)"
            )
        t, p, q, line, n_dup = _drop_repeated_stamps(path, t, p, q, line, time_unit, row_word)
    df = pd.DataFrame({"t_ns": t, "t_s": seconds_from_ns(t), "x_m": p[:, 0], "y_m": p[:, 1], "z_m": p[:, 2],
                       "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3], "line": line})  # fmt: skip
    df.attrs = {"path": str(path), "format": fmt, "time_unit": time_unit, "n_rows_file": n_rows,
                "n_duplicates_dropped": n_dup, "n_quats_renormalised": n_renorm,
                "max_quat_norm_error": max_err, **(attrs or {})}  # fmt: skip
    return df


def stream_T(stream: pd.DataFrame) -> np.ndarray:
    """The poses of a stream table as transforms ``T_A_X``, shape (N, 4, 4), metres.

    Parameters
    ----------
    stream : DataFrame
        A stream table (``x_m y_m z_m qx qy qz qw``).

    Returns
    -------
    ndarray, shape (N, 4, 4)
    """
    return make_T(R_from_quat(stream[["qx", "qy", "qz", "qw"]].to_numpy(float)),
                  stream[["x_m", "y_m", "z_m"]].to_numpy(float))  # fmt: skip


def stream_export(stream: pd.DataFrame, fmt: str) -> MocapExport:
    """A pose stream as a motion-capture export: one body, named by the file's stem.

    Parameters
    ----------
    stream : DataFrame
        A stream table with ``attrs["path"]``.
    fmt : str
        The format's key.

    Returns
    -------
    MocapExport
        ``bodies``: the ``bodies.parquet`` columns plus ``t_ns`` (``fit_rms_m`` NaN,
        ``n_markers`` -1: a stream carries no residual); ``markers`` without marker columns;
        ``rate_hz`` 1 / the median interval; ``stream`` the table itself.
    """
    path = Path(stream.attrs["path"])
    t_ns = stream["t_ns"].to_numpy(np.int64)
    rate = 1e9 / float(np.median(np.diff(t_ns))) if len(t_ns) > 1 else float("nan")
    frame = np.arange(len(stream))
    n = len(stream)
    bodies = bodies_from_poses(frame, stream["t_s"].to_numpy(float), path.stem, stream_T(stream),
                               np.full(n, np.nan), np.full(n, -1))  # fmt: skip
    bodies["t_ns"] = t_ns
    markers = marker_table(frame, np.zeros((n, 0, 3)), [], rate if np.isfinite(rate) else 1.0)
    markers["t_s"] = stream["t_s"].to_numpy(float)
    meta = {k: v for k, v in stream.attrs.items() if isinstance(v, (str, int, float))}
    return MocapExport(path, fmt, rate, markers, bodies, meta, stream)


def read_positional(path, key: str, title: str, reject=None, *, in_time_order: bool = True,
                    quat_tol: float = QUAT_NORM_TOL) -> pd.DataFrame:  # fmt: skip
    """The stream table of a file of positional rows ``t x y z qx qy qz qw``, times in seconds.

    Parameters
    ----------
    path : str or Path
    key, title : str
        The format's key and name (for the table and messages).
    reject : callable, optional
        ``reject(layout) -> str or None``: why the file is not of this format (a format's own
        contradiction, e.g. commas in a TUM file).
    in_time_order : bool
        The time-order policy of this module (False: file order).
    quat_tol : float
        Largest accepted | |q| - 1 |.

    Returns
    -------
    DataFrame
        :data:`STREAM_COLUMNS`.

    Raises
    ------
    PoseFormatError
        No row of numbers, rows of other than 8 fields, times of ns, what ``reject`` says.
    QuaternionNormError, TimestampOrderError
        :func:`stream_table`.
    """
    path = Path(path)
    lay = stream_layout(read_head(path))
    row = "t x y z qx qy qz qw"
    if lay.first_data_line is None:
        raise PoseFormatError(f"{path}: no row of numbers; expected a {title}")
    why = reject(lay) if reject is not None else None
    if why:
        raise PoseFormatError(f"{path}: not a {title}: {why}")
    if lay.n_fields != 8:
        raise PoseFormatError(f"{path}, line {lay.first_data_line}: {lay.n_fields} fields; "
                              f"expected 8 ({row})")  # fmt: skip
    if looks_ns(lay.first_time):
        raise PoseFormatError(f"{path}, line {lay.first_data_line}: time {lay.first_time} is an integer of "
                              f"{len(lay.first_time)} digits, nanoseconds; {key.upper()} times are in "
                              "seconds")  # fmt: skip
    t_ns, values, line = read_rows(path, lay, list(range(8)), "s", row)
    return stream_table(path, key, t_ns, values, line, time_unit="s", quat_tol=quat_tol,
                        in_time_order=in_time_order)  # fmt: skip


def _export_of(read_stream, key, path) -> MocapExport:
    return stream_export(read_stream(path), key)


def pose_stream_format(key: str, title: str, detect, read_stream) -> MocapFormat:
    """The registry entry of a pose-stream format (its ``read`` is :func:`stream_export` of ``read_stream``).

    Parameters
    ----------
    key, title : str
        The format's key and name.
    detect : callable
        ``detect(head) -> str or None``.
    read_stream : callable
        ``read_stream(path, in_time_order=True) -> DataFrame`` (the stream table).

    Returns
    -------
    MocapFormat
    """
    return MocapFormat(key, title, "poses", detect, partial(_export_of, read_stream, key), read_stream)
