"""Motion-capture files of any make: the format registry, detection from the content, one entry point.

Two kinds of file are read. *Marker exports* give the marker table of
:mod:`cvsflow.io.mocap.markers` (``frame``, ``t_s``, ``{name}_{x,y,z}_m`` in metres in the
system's world frame W, NaN where unseen) and, where the export also holds the system's own
rigid-body solution (Motive rigid bodies, QTM 6DOF bodies), the *system bodies table*
(:data:`cvsflow.mocap.bodies.BODY_COLUMNS`, ``fit_rms_m`` the system's own residual, ``n_markers``
-1 when the export does not say). *Pose streams* (ASL/EuRoC, TUM, ETH CSVs) give one body's
pose per row with exact nanosecond times: the stream table of :mod:`cvsflow.io.mocap.streams`
(:func:`read_pose_stream`), and as an export a bodies table of that one body.

Each format is one module with a :class:`~cvsflow.io.mocap.markers.MocapFormat` (its key, name,
kind, ``detect`` and ``read``) and one line of :data:`REGISTRY`. Adding a format is that module,
that line and its test. The format is found from the first bytes of the file (the registry's
detectors, in order), never from its suffix, so a file of the wrong kind (a Nexus Devices-only
export, a TRC file, a frame list) is named for what it is, with what was expected.
"""

from __future__ import annotations

import logging
from pathlib import Path

import pandas as pd

from cvsflow.exceptions import ConfigError, InputError, PoseFormatError
from cvsflow.io.mocap import asl, eth, optitrack, qualisys, tum, vicon
from cvsflow.io.mocap.markers import MocapExport, MocapFormat, marker_names, read_head, select_markers
from cvsflow.io.mocap.stream_layout import describe_layout, stream_layout
from cvsflow.mocap import select_system_bodies

log = logging.getLogger(__name__)

#: The formats, in the order detection tries them (TUM before ETH: white-space rows of 8
#: numbers are both; the first to claim a file names it under ``auto``).
REGISTRY: tuple[MocapFormat, ...] = (
    vicon.NEXUS_CSV,
    vicon.C3D,
    optitrack.FORMAT,
    qualisys.FORMAT,
    asl.FORMAT,
    tum.FORMAT,
    eth.FORMAT,
)
BY_KEY = {f.key: f for f in REGISTRY}
#: Format keys with a human name each (used in messages and the config schema).
FORMATS = {f.key: f.title for f in REGISTRY}
MARKER_FORMATS = tuple(f.key for f in REGISTRY if f.kind == "markers")
POSE_STREAM_FORMATS = tuple(f.key for f in REGISTRY if f.kind == "poses")
EXPECTED = (
    "expected a motion-capture export (" + ", ".join(BY_KEY[k].title for k in MARKER_FORMATS)
    + ") or a pose stream (" + "; ".join(BY_KEY[k].title for k in POSE_STREAM_FORMATS) + ")"
)


def detect(path) -> tuple[MocapFormat, str]:
    """The format of a file from its content, and why.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    fmt : MocapFormat
        The first entry of :data:`REGISTRY` whose ``detect`` claims the file.
    reason : str
        What it saw (for messages).

    Raises
    ------
    InputError
        Missing file or a folder; a file of another kind: the message says what it looks like
        (an empty file, a binary file that is not C3D, a TRC file, a Nexus Devices-only
        export, a QTM 2D export, rows of numbers no stream format reads) and what was expected.
    """
    head = read_head(path)
    for fmt in REGISTRY:
        reason = fmt.detect(head)
        if reason:
            return fmt, reason
    path = head.path
    if not head.raw.strip():
        raise InputError(f"{path}: empty file, {EXPECTED}")
    if head.binary:
        raise InputError(f"{path}: a binary file that is not C3D (no 0x50 key in byte 2), {EXPECTED}")
    first = head.lines[0].strip() if head.lines else ""
    if first.split("\t")[0].strip().startswith("PathFileType"):
        raise InputError(
            f"{path}: a TRC marker file (Motion Analysis / OpenSim), which cvsflow does not read; "
            f"{EXPECTED}. Export CSV from Motive or TSV from QTM instead"
        )
    if "filename" in first.lower().replace(" ", "").split(","):
        raise InputError(
            f"{path}: a frame list ({first[:60]!r}: a camera's images by timestamp, as an ASL "
            f"folder's cam0/data.csv), not motion capture; {EXPECTED}"
        )
    rows = describe_layout(stream_layout(head))
    if rows is not None:
        raise PoseFormatError(f"{path}: format not recognised: {rows}; {EXPECTED}")
    raise InputError(f"{path}, line 1: unrecognised content {first[:60]!r}; {EXPECTED}")


def detect_format(path) -> str:
    """The key of a file's format, from its content (:func:`detect`).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    str
        A key of :data:`FORMATS` (``vicon_csv``, ``c3d``, ``motive_csv``, ``qtm_tsv``, ``asl``,
        ``tum``, ``eth``).

    Raises
    ------
    InputError
        As :func:`detect`.
    """
    return detect(path)[0].key


def _resolve(path, format: str, given_by: str) -> MocapFormat:
    """The format to read ``path`` with: detected under ``auto``, else the one given, checked."""
    path = Path(path)
    if format != "auto" and format not in BY_KEY:
        raise InputError(f"{path}: unknown format {format!r} (expected auto or one of {sorted(BY_KEY)})")
    if format == "auto":
        return detect(path)[0]
    given = BY_KEY[format]
    head = read_head(path)
    if given.detect(head):
        return given
    try:
        found, reason = detect(path)
    except InputError:
        return given  # nothing else claims it: the given reader says what is wrong
    error = PoseFormatError if "poses" in (given.kind, found.kind) else InputError
    raise error(
        f"{path}: {given_by} says {given.title} ({given.key}) but the file is {found.a_title} "
        f"({found.key}: {reason}); set the format to {found.key} or auto, or name the right file"
    )


def read_mocap(path, format: str = "auto", given_by: str = "the config") -> MocapExport:
    """Read any supported motion-capture export or pose stream.

    Parameters
    ----------
    path : str or Path
    format : str
        ``auto`` (detect from the content) or a key of :data:`FORMATS`. A named format that
        another format's detector claims the file for is an error (a config naming the wrong
        system), which names both.
    given_by : str
        Who named the format, for that message (``the config``, ``--pose-format``).

    Returns
    -------
    MocapExport

    Raises
    ------
    InputError
        Unknown format name; content of another kind (:func:`detect`); the reader's errors
        (file and line of any bad cell).
    """
    fmt = _resolve(path, format, given_by)
    return fmt.read(Path(path))


def read_pose_stream(path, format: str = "auto", in_time_order: bool = True,
                     given_by: str = "the format given") -> pd.DataFrame:  # fmt: skip
    """Read a time-stamped pose stream (ASL/EuRoC, TUM or ETH CSV) into the stream table.

    Parameters
    ----------
    path : str or Path
    format : str
        ``auto`` or a key of :data:`POSE_STREAM_FORMATS`; a file the format contradicts is an
        error saying what it is.
    in_time_order : bool
        True: a stream, in time order (rows repeating a timestamp dropped with a warning, a
        time going back an error; :mod:`cvsflow.io.mocap.streams`). False: a pose list in file
        order, every row kept.
    given_by : str
        Who named the format, for messages.

    Returns
    -------
    DataFrame
        :data:`cvsflow.io.mocap.streams.STREAM_COLUMNS` (exact ``t_ns``), ``attrs`` with the
        format, the columns found and the rows dropped.

    Raises
    ------
    PoseFormatError
        Not a pose stream (a marker export is named), or a format the content contradicts.
    MissingColumnError, QuaternionNormError, TimestampOrderError
        The reader's checks (file and line named).
    """
    fmt = _resolve(path, format, given_by)
    if fmt.kind != "poses":
        raise PoseFormatError(
            f"{path}: {fmt.a_title} ({fmt.key}), a marker export, not a pose stream; expected "
            + "; or ".join(BY_KEY[k].a_title for k in POSE_STREAM_FORMATS)
        )
    return fmt.read_stream(Path(path), in_time_order=in_time_order)


def read_markers(path, names=None, format="auto") -> pd.DataFrame:
    """Read the markers of a motion-capture export (Vicon, OptiTrack, Qualisys), optionally selecting some.

    Parameters
    ----------
    path : str or Path
        The export: Vicon Nexus Trajectories CSV, C3D, OptiTrack Motive CSV or Qualisys QTM
        3D TSV. The format is found from the content (:func:`detect_format`),
        not the suffix.
    names : sequence of str, optional
        Marker names to keep (as in the export, e.g. ``Subject:Marker``), in this order. Each
        must be present and seen in at least one frame.
    format : str
        ``auto`` or a format of :data:`FORMATS` (``mocap.format``);
        a named format the content contradicts is an error.

    Returns
    -------
    markers : DataFrame
        Wide marker table, metres in W (module docstring). A Motive export without plain
        ``Marker`` columns gives its ``Rigid Body Marker`` positions instead (with a warning).
        ``attrs``: ``format``, ``n_frames_stated`` (the header's frame count, None when the
        format states none) and ``warnings`` (a file cut short: both counts), for
        :func:`cvsflow.io.mocap.markers.import_summary`.

    Raises
    ------
    InputError
        File missing or of another kind (a Nexus Devices-only export, a pose stream: the
        message says what it is and what was expected); the reader's errors; an export
        without markers (a QTM 6D file: use ``mocap.bodies_from: system``); a configured
        marker missing from the file (the message lists the file's markers) or never seen.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    export = read_mocap(path, format)
    if export.stream is not None:
        raise InputError(
            f"{path}: {BY_KEY[export.format].a_title}, the poses of one body, not a motion-capture "
            "export of markers; expected " + ", ".join(BY_KEY[k].title for k in MARKER_FORMATS)
        )
    df = export.markers
    if not marker_names(df):
        solved = export.meta.get("body_markers")
        if solved is not None and marker_names(solved):
            log.warning("%s: no Marker columns; using the Rigid Body Marker (solved) positions", path)
            df = _carry_read_notes(df, solved)
        else:
            have = ", ".join(map(repr, export.body_names)) or "none"
            raise InputError(
                f"{path}: {BY_KEY[export.format].a_title} without marker positions (its rigid bodies: "
                f"{have}); expected marker columns, or set the session's mocap.bodies_from: "
                "system to use the system's own body poses"
            )
    if names is not None:
        df = select_markers(df, names, source=path)
    return df


def read_system_bodies(path, names, format: str = "auto") -> pd.DataFrame:
    """The camera and board poses as the mocap system solved them, renamed to the pipeline's bodies.

    Parameters
    ----------
    path : str or Path
        A Motive CSV with Rigid Body columns or a QTM 6D TSV.
    names : dict
        ``{"camera": <system body name>, "board": <system body name>}``.
    format : str
        ``auto`` or a key of :data:`FORMATS`.

    Returns
    -------
    bodies : DataFrame
        ``bodies.parquet`` table (``body`` = ``camera`` / ``board``), ``fit_rms_m`` the system's
        residual in metres, ``attrs["rate_hz"]`` and ``attrs["residual"]`` (what the residual is).

    Raises
    ------
    InputError
        The export holds no rigid-body poses (a Vicon CSV or C3D, a Motive markers-only export,
        a QTM 3D export), or the reader's errors.
    MocapError
        A named body absent from the export (the message lists the export's bodies) or never
        tracked.
    """
    export = read_mocap(path, format)
    if export.bodies is None:
        n = len(export.markers.attrs.get("markers", []))
        raise InputError(
            f"{path}: {BY_KEY[export.format].a_title} with {n} markers and no rigid-body poses; "
            "bodies_from: system needs the system's own bodies (Motive: export Rigid Bodies; "
            "QTM: export 6DOF data as TSV). Use bodies_from: markers to fit the markers instead"
        )
    out = select_system_bodies(export.bodies, names, source=str(path))
    out.attrs["rate_hz"] = export.rate_hz
    return _carry_read_notes(export.markers, out)


def _carry_read_notes(source: pd.DataFrame, table: pd.DataFrame) -> pd.DataFrame:
    """``table`` with the reader's notes on ``source`` (format, stated count, warnings) in attrs."""
    for key in ("format", "n_frames_stated", "warnings"):
        if key in source.attrs:
            table.attrs[key] = source.attrs[key]
    return table


def mocap_settings(session: str, cfg: dict) -> dict:
    """A session's ``mocap`` block with its defaults, checked against its ``markers`` block.

    Parameters
    ----------
    session : str
        Session key, for messages.
    cfg : dict
        ``config["sessions"][session]``.

    Returns
    -------
    settings : dict
        ``{"format": str, "bodies_from": "markers" | "system"}``.

    Raises
    ------
    ConfigError
        A ``format`` that is not a marker export's key of :data:`FORMATS` (a pose stream's
        named as such); ``bodies_from: system`` with a body lacking ``system_body``, or
        ``bodies_from: markers`` with a body lacking ``names``.
    """
    out = {"format": "auto", "bodies_from": "markers", **(cfg.get("mocap") or {})}
    if out["format"] != "auto" and out["format"] not in MARKER_FORMATS:
        what = (f"{BY_KEY[out['format']].a_title}: the poses of one body, which cannot give a "
                "session's camera and board bodies" if out["format"] in BY_KEY else "unknown")  # fmt: skip
        raise ConfigError(
            f"config: sessions.{session}.mocap.format: {out['format']!r} is {what}; expected auto "
            f"or a motion-capture export's format: {', '.join(MARKER_FORMATS)}"
        )
    need = "system_body" if out["bodies_from"] == "system" else "names"
    for body in ("camera", "board"):
        spec = (cfg.get("markers") or {}).get(body, {})
        if need not in spec:
            hint = ("the rigid body's name in the Motive / QTM export" if need == "system_body"
                    else "the body's marker names in the export")
            raise ConfigError(
                f"config: sessions.{session}.markers.{body}: mocap.bodies_from is "
                f"{out['bodies_from']}, so {need} is needed ({hint})"
            )
    return out
