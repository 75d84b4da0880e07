"""The in-memory tables every motion-capture reader produces, whatever the make.

The *marker table* is a wide DataFrame at the export's native rate: columns ``frame`` (int,
0-based), ``t_s`` (float, frame / rate), then for every marker ``{name}_x_m``, ``{name}_y_m``,
``{name}_z_m`` in metres in the system's world frame W, NaN where the marker was not seen.
``df.attrs["rate_hz"]`` carries the rate and ``df.attrs["markers"]`` the marker names in file
order. The *system bodies table* (an export's own rigid-body solution) has the
``bodies.parquet`` columns of :data:`cvsflow.mocap.bodies.BODY_COLUMNS`. :class:`MocapExport` holds one
export read into these. A *pose stream* (ASL, TUM, ETH CSV: one body's pose per row) is read
into the stream table of :mod:`cvsflow.io.mocap.streams` and held as its ``stream``.

:class:`MocapFormat` is one entry of the format registry (:mod:`cvsflow.io.mocap.formats`):
a format's module defines one, and :class:`FileHead` is what its ``detect`` looks at.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError
from cvsflow.geometry import make_T
from cvsflow.mocap import bodies_from_poses

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")


def marker_columns(name: str) -> list[str]:
    """The three column names of one marker in a marker table.

    Parameters
    ----------
    name : str
        Marker name.

    Returns
    -------
    list of str
        ``[name_x_m, name_y_m, name_z_m]``.
    """
    return [f"{name}_{a}_m" for a in AXES]


def marker_names(df: pd.DataFrame) -> list[str]:
    """Marker names of a wide marker table, in column order.

    Parameters
    ----------
    df : DataFrame
        Wide marker table.

    Returns
    -------
    list of str
        ``df.attrs["markers"]`` when set, else the prefixes of the ``*_x_m`` columns.
    """
    if "markers" in df.attrs:
        return list(df.attrs["markers"])
    return [c[: -len("_x_m")] for c in df.columns if c.endswith("_x_m")]


def marker_table(frame0, xyz_m, names, rate_hz) -> pd.DataFrame:
    """Assemble the wide marker table from 0-based frames and (n_frames, n_markers, 3) metres.

    Parameters
    ----------
    frame0 : array_like of int, shape (N,)
        0-based frame numbers.
    xyz_m : ndarray, shape (N, M, 3)
        Marker positions in the system's world W, metres; NaN where not seen.
    names : sequence of str, length M
        Marker names, in file order.
    rate_hz : float
        Native frame rate, Hz.

    Returns
    -------
    markers : DataFrame
        ``frame``, ``t_s`` = frame / rate_hz (s), ``{name}_{x,y,z}_m``; ``attrs["rate_hz"]``
        and ``attrs["markers"]`` set.
    """
    frame0 = np.asarray(frame0, dtype=np.int64)
    data = {"frame": frame0, "t_s": frame0 / float(rate_hz)}
    for k, name in enumerate(names):
        for a, axis in enumerate(AXES):
            data[f"{name}_{axis}_m"] = xyz_m[:, k, a]
    df = pd.DataFrame(data)
    df.attrs["rate_hz"] = float(rate_hz)
    df.attrs["markers"] = list(names)
    return df


def note_frame_count(df: pd.DataFrame, path, n_stated=None, stated_by="", cut_line=None) -> None:
    """Record on a marker table the frame count its export states; warn when the file was cut.

    A take cut short (an export or copy interrupted) is used as far as it goes, as a video
    whose last frames do not decode is: one WARNING names both counts, and the same text goes
    to ``df.attrs["warnings"]`` for the stage's summary (:func:`import_summary`).

    Parameters
    ----------
    df : DataFrame
        The marker table as read (``frame``, ``t_s``, ``attrs["rate_hz"]``); its ``attrs`` are
        updated in place.
    path : str or Path
        The export, for the message.
    n_stated : int, optional
        Frames the export's header states; None when the format states none (Nexus CSV).
    stated_by : str
        Where the header states it (``Total Exported Frames``, ``NO_OF_FRAMES``, ...).
    cut_line : int, optional
        1-based line of a last row cut mid-row and left out.

    Returns
    -------
    None
        Sets ``attrs["n_frames_stated"]`` (int or None) and appends to ``attrs["warnings"]``.
    """
    n_read = len(df)
    rate = float(df.attrs.get("rate_hz", float("nan")))
    df.attrs["n_frames_stated"] = None if n_stated is None else int(n_stated)
    df.attrs.setdefault("warnings", [])
    cut = f"; its last row (line {cut_line}) was cut mid-row and left out" if cut_line else ""
    if n_stated is not None and n_read < n_stated:
        text = (f"{path}: the file was cut short: {n_read} of the {n_stated} frames its header "
                f"states ({stated_by}) were read ({n_read / rate:.3f} of {n_stated / rate:.3f} s "
                f"at {rate:g} Hz; an interrupted export or copy?){cut}; the take is used as far "
                "as it goes")
    elif n_stated is not None and n_read > n_stated:
        text = (f"{path}: {n_read} frames read, its header states {n_stated} ({stated_by}); all "
                f"{n_read} are used{cut}")
    elif cut_line:
        text = (f"{path}: the file was cut short: its last row (line {cut_line}) was cut mid-row "
                f"and left out; {n_read} whole frames read ({n_read / rate:.3f} s at {rate:g} Hz; "
                "an interrupted export or copy?)")
    else:
        return
    log.warning(text)
    df.attrs["warnings"] = [*df.attrs["warnings"], text]


def import_summary(df: pd.DataFrame, path) -> dict:
    """What an import read, for the stage's YAML summary.

    Parameters
    ----------
    df : DataFrame
        A marker (or system bodies) table as a reader returned it.
    path : str or Path
        The export.

    Returns
    -------
    dict
        ``file``, ``format``, ``rate_hz`` (Hz), ``n_frames`` (frames read), ``n_frames_stated``
        (the header's count, None when the format states none), ``t_span_s`` ([first, last]
        frame time, s) and ``warnings`` (the reader's, e.g. a file cut short).
    """
    frames = pd.unique(df["frame"]) if len(df) else np.zeros(0, np.int64)
    t = df["t_s"].to_numpy(float) if len(df) else np.zeros(0)
    return {
        "file": str(path),
        "format": df.attrs.get("format"),
        "rate_hz": float(df.attrs["rate_hz"]) if "rate_hz" in df.attrs else None,
        "n_frames": int(len(frames)),
        "n_frames_stated": df.attrs.get("n_frames_stated"),
        "t_span_s": [float(t.min()), float(t.max())] if t.size else None,
        "warnings": list(df.attrs.get("warnings", [])),
    }


def select_markers(df: pd.DataFrame, names, source="marker table") -> pd.DataFrame:
    """Keep only the named markers; each must exist and be seen at least once.

    Parameters
    ----------
    df : DataFrame
        Wide marker table.
    names : sequence of str
        Markers to keep, in the order wanted.
    source : str, default "marker table"
        What the table was read from (file name), for the error messages.

    Returns
    -------
    markers : DataFrame
        A copy with ``frame``, ``t_s`` and the named markers' columns; ``attrs`` copied with
        ``attrs["markers"]`` = ``names``.

    Raises
    ------
    InputError
        A name absent from the table (lists what it has), a marker empty for the whole take,
        or one of its coordinate columns empty for the whole take (marker and column named).
    """
    have = marker_names(df)
    missing = [n for n in names if n not in have]
    if missing:
        raise InputError(
            f"{source}: marker(s) {missing} not in the file (it has {len(have)} markers: "
            f"{', '.join(have)})"
        )
    for n in names:
        seen = np.isfinite(df[marker_columns(n)].to_numpy()).any(axis=0)
        if not seen.any():
            raise InputError(
                f"{source}: marker {n!r} is absent for the whole take "
                f"({len(df)} frames, every cell empty); expected it seen in at least one frame"
            )
        if not seen.all():
            # a whole coordinate column lost (an edited or damaged export): the marker would be
            # a gap in every frame, silently rebuilt from the layout
            empty = [a.upper() for a, s in zip(AXES, seen, strict=True) if not s]
            have = [a.upper() for a, s in zip(AXES, seen, strict=True) if s]
            raise InputError(
                f"{source}: marker {n!r}: its {'/'.join(empty)} column is empty in all "
                f"{len(df)} frames while {'/'.join(have)} hold values; expected X, Y and Z (a "
                "column lost in an edit or export?). Re-export the take, or leave the marker "
                "out of the body's names and layout_m"
            )
    out = df[["frame", "t_s"] + [c for n in names for c in marker_columns(n)]].copy()
    out.attrs = dict(df.attrs)
    out.attrs["markers"] = list(names)
    return out


@dataclass
class MocapExport:
    """One motion-capture export, read.

    Attributes
    ----------
    path : Path
    format : str
        A key of :data:`FORMATS`.
    rate_hz : float
        Frame rate of the export, Hz.
    markers : DataFrame
        Wide marker table (module docstring); may have no marker columns (a 6DOF-only export).
    bodies : DataFrame or None
        System bodies table (module docstring), or None when the export holds no bodies.
    meta : dict
        Header values of the export (plain str/int/float), e.g. units, take name.
    stream : DataFrame or None
        A pose stream's table (:data:`cvsflow.io.mocap.streams.STREAM_COLUMNS`: exact
        ``t_ns``), None for a marker export.
    """

    path: Path
    format: str
    rate_hz: float
    markers: pd.DataFrame
    bodies: pd.DataFrame | None = None
    meta: dict = field(default_factory=dict)
    stream: pd.DataFrame | None = None

    @property
    def body_names(self) -> list[str]:
        """Names of the system's bodies, in file order (empty without bodies)."""
        if self.bodies is None:
            return []
        return list(pd.unique(self.bodies["body"]))


def system_bodies_table(frame, t_s, body, R_W_body, t_W_body_m, residual_m, n_markers) -> pd.DataFrame:
    """A system bodies table for one body (``bodies.parquet`` columns) from rotations and positions.

    Parameters
    ----------
    frame : ndarray of int, shape (N,)
    t_s : ndarray, shape (N,)
    body : str
    R_W_body : ndarray, shape (N, 3, 3)
        Rotation of the body in W; NaN rows where the system lost the body.
    t_W_body_m : ndarray, shape (N, 3)
        Body origin in W, metres; NaN where lost.
    residual_m : ndarray, shape (N,)
        The system's residual, metres.
    n_markers : ndarray of int, shape (N,)
        Markers used per frame, -1 when unknown.

    Returns
    -------
    bodies : DataFrame
        The ``bodies.parquet`` columns (T_W_body as ``x_m .. qw``), ``valid`` False on the
        NaN rows; see :func:`cvsflow.mocap.bodies.bodies_from_poses`.
    """
    T = make_T(np.asarray(R_W_body, float), np.asarray(t_W_body_m, float))
    return bodies_from_poses(frame, t_s, body, T, residual_m, n_markers)


#: Bytes of a file's start that format detection looks at.
HEAD_BYTES = 65536


@dataclass
class FileHead:
    """The start of a file, as format detection sees it.

    Attributes
    ----------
    path : Path
    raw : bytes
        The first :data:`HEAD_BYTES` bytes.
    memo : dict
        Whatever a detector computed and another may reuse (e.g. the pose-stream layout).
    """

    path: Path
    raw: bytes
    memo: dict = field(default_factory=dict)

    @cached_property
    def lines(self) -> list[str]:
        """The decoded lines (a last line cut by the read left out)."""
        lines = self.raw.decode("utf-8-sig", errors="replace").splitlines()
        if len(self.raw) == HEAD_BYTES and len(lines) > 1:
            lines = lines[:-1]
        return lines

    @property
    def binary(self) -> bool:
        """Whether the start holds a NUL byte (not a text export)."""
        return b"\x00" in self.raw


def read_head(path, expected: str = "a motion-capture export or a pose stream") -> FileHead:
    """The start of a file for format detection; InputError when it is missing or a folder.

    Parameters
    ----------
    path : str or Path
    expected : str
        What the file should be, for the message.

    Returns
    -------
    FileHead
    """
    path = Path(path)
    try:
        with open(path, "rb") as fh:
            return FileHead(path, fh.read(HEAD_BYTES))
    except FileNotFoundError as exc:
        raise InputError(f"{path}: file not found ({expected})") from exc
    except IsADirectoryError as exc:
        raise InputError(f"{path}: is a folder, {expected}") from exc


@dataclass(frozen=True)
class MocapFormat:
    """One motion-capture format: its key, its name, how it is recognised and read.

    Attributes
    ----------
    key : str
        The name a config or ``--pose-format`` gives (``vicon_csv``, ``asl``, ...).
    title : str
        A human name for messages (``Vicon Nexus Trajectories CSV``).
    kind : {"markers", "poses"}
        ``markers``: an export of marker positions (with or without the system's bodies);
        ``poses``: a time-stamped pose stream of one body.
    detect : callable
        ``detect(head: FileHead) -> str or None``: why the file is of this format (a short
        reason, for messages), None when it is not. It may raise :class:`InputError` for a
        file that is of this make but of a kind cvsflow cannot use (a Nexus Devices-only
        export), saying what to export instead.
    read : callable
        ``read(path) -> MocapExport``.
    read_stream : callable or None
        Pose streams only: ``read_stream(path, in_time_order=True) -> DataFrame``, the stream
        table of :mod:`cvsflow.io.mocap.streams` (``in_time_order=False``: a pose list in file
        order).
    """

    key: str
    title: str
    kind: str
    detect: Callable[[FileHead], str | None]
    read: Callable[[Path], MocapExport]
    read_stream: Callable[..., pd.DataFrame] | None = None

    @property
    def a_title(self) -> str:
        """The title with its indefinite article (an ASL ..., a TUM ...)."""
        return ("an " if self.title[0] in "AEIOU" else "a ") + self.title
