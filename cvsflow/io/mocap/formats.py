"""Motion-capture exports of any make: format detection from the content, and one entry point.

Four formats are read into the same tables: Vicon Nexus 'Trajectories' CSV (``vicon_csv``),
C3D (``c3d``), OptiTrack Motive CSV (``motive_csv``, :mod:`cvsflow.io.mocap.optitrack`) and Qualisys
QTM TSV (``qtm_tsv``, :mod:`cvsflow.io.mocap.qualisys`). The *marker table* is the wide table of
:mod:`cvsflow.io.mocap.markers` (``frame``, ``t_s``, ``{name}_{x,y,z}_m`` in metres in the system's world
frame W, NaN where unseen, ``attrs["rate_hz"]``, ``attrs["markers"]``). Where the export also
holds the system's own rigid-body solution (Motive rigid bodies, QTM 6DOF bodies), the *system
bodies table* has the ``bodies.parquet`` columns (:data:`cvsflow.mocap.bodies.BODY_COLUMNS`) with the
body named as in the export, ``fit_rms_m`` the system's own residual in metres (Motive: Mean
Marker Error; QTM: the 6DOF residual), ``n_markers`` the markers the system used (-1 when the
export does not say), ``n_filled`` 0.

The format is found from the first bytes of the file, never from its suffix alone, so a file
of the wrong kind (a Nexus Devices-only export, a TUM pose list, a TRC file) is named for what it
is, with what was expected.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import pandas as pd

from cvsflow.exceptions import ConfigError, InputError
from cvsflow.io.mocap.markers import MocapExport, marker_names, select_markers
from cvsflow.io.mocap.optitrack import read_motive_csv
from cvsflow.io.mocap.qualisys import read_qtm_tsv
from cvsflow.io.mocap.vicon import read_c3d, read_nexus_csv
from cvsflow.mocap import select_system_bodies

log = logging.getLogger(__name__)

#: Formats the readers understand, with a human name each (used in messages).
FORMATS = {
    "vicon_csv": "Vicon Nexus Trajectories CSV",
    "c3d": "C3D",
    "motive_csv": "OptiTrack Motive CSV",
    "qtm_tsv": "Qualisys QTM TSV",
}
EXPECTED = (
    "expected a motion-capture export: Vicon Nexus Trajectories CSV, C3D, OptiTrack Motive CSV "
    "(format 1.2x) or Qualisys QTM TSV (3D or 6D)"
)

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TUM_LINE = re.compile(rf"^\s*{_NUMBER}(?:[ \t]+{_NUMBER}){{7}}\s*$")


def _head(path: Path, n_bytes: int = 65536) -> bytes:
    try:
        with open(path, "rb") as fh:
            return fh.read(n_bytes)
    except FileNotFoundError as exc:
        raise InputError(f"{path}: file not found ({EXPECTED})") from exc
    except IsADirectoryError as exc:
        raise InputError(f"{path}: is a folder, {EXPECTED}") from exc


def _first_cells(lines, sep=","):
    return [ln.split(sep)[0].strip().strip('"') for ln in lines]


def detect_format(path) -> str:
    """The format of a motion-capture export, from its content.

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    fmt : str
        ``vicon_csv``, ``c3d``, ``motive_csv`` or ``qtm_tsv``.

    Raises
    ------
    InputError
        The file is of another kind. The message says what it looks like (a Vicon Nexus export
        with only a Devices block, a TUM pose list, a TRC file, a QTM 2D or analog export, an
        empty file) and what was expected.
    """
    path = Path(path)
    head = _head(path)
    if len(head) >= 512 and head[1] == 0x50 and b"\x00" in head[:512]:
        return "c3d"  # C3D: byte 2 of the header block is the parameter key 0x50
    if not head.strip():
        raise InputError(f"{path}: empty file, {EXPECTED}")
    if b"\x00" in head:
        raise InputError(f"{path}: a binary file that is not C3D (no 0x50 key in byte 2), {EXPECTED}")
    text = head.decode("utf-8-sig", errors="replace")
    lines = text.splitlines()
    if len(head) == 65536 and len(lines) > 1:
        lines = lines[:-1]  # the last line of a partial read may be cut
    first = lines[0].strip()
    if first.startswith("Format Version,") or first.startswith('"Format Version",'):
        return "motive_csv"
    key = first.split("\t")[0].strip()
    if key in ("FILE_VERSION", "NO_OF_FRAMES"):
        included = next((ln.split("\t")[1].strip() for ln in lines if ln.startswith("DATA_INCLUDED\t")), None)
        if included in (None, "3D", "6D"):
            return "qtm_tsv"
        raise InputError(
            f"{path}: a Qualisys QTM TSV with DATA_INCLUDED {included!r} (expected 3D markers or "
            "6D bodies: export 3D data (.tsv) or 6DOF data (_6d.tsv) from QTM)"
        )
    if key.startswith("PathFileType"):
        raise InputError(
            f"{path}: a TRC marker file (Motion Analysis / OpenSim), which cvsflow does not read; "
            f"{EXPECTED}. Export CSV from Motive or TSV from QTM instead"
        )
    cells = _first_cells(lines)
    if "Trajectories" in cells:
        return "vicon_csv"
    if cells[0] in ("Devices", "Model Outputs", "Segments", "Joints"):
        sections = _nexus_sections(path)
        if "Trajectories" in sections:
            return "vicon_csv"
        rate = lines[1].split(",")[0].strip() if len(lines) > 1 else "?"
        raise InputError(
            f"{path}: a Vicon Nexus CSV with only the block(s) {', '.join(sections)} "
            f"({cells[0]} at {rate} Hz: analog, force-plate or EMG channels), no Trajectories "
            "block, so no marker positions. Expected the Trajectories (marker) export: in Nexus, "
            "Export CSV with 'Trajectories' ticked"
        )
    data = [ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#")]
    if data and sum(bool(_TUM_LINE.match(ln)) for ln in data[:20]) == len(data[:20]):
        raise InputError(
            f"{path}: a TUM pose list (lines 'timestamp tx ty tz qx qy qz qw'), that is poses, "
            f"not a motion-capture export of markers; {EXPECTED}"
        )
    raise InputError(f"{path}, line 1: unrecognised content {first[:60]!r}; {EXPECTED}")


def _nexus_sections(path: Path) -> list[str]:
    """Names of the Nexus CSV blocks (a block name is a line of one word followed by the rate)."""
    names = []
    prev_blank = True
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for line in fh:
            cell = line.split(",")[0].strip()
            rest = line.strip().strip(",").strip()
            if prev_blank and cell in ("Devices", "Trajectories", "Model Outputs", "Segments", "Joints") \
                    and rest == cell:
                names.append(cell)
            prev_blank = not line.strip(", \t\r\n")
    return names


def read_mocap(path, format: str = "auto") -> MocapExport:
    """Read any supported motion-capture export.

    Parameters
    ----------
    path : str or Path
    format : str
        ``auto`` (detect from the content) or a key of :data:`FORMATS`. A named format that
        disagrees with the content is an error (a config naming the wrong system).

    Returns
    -------
    MocapExport

    Raises
    ------
    InputError
        Unknown format name; content of another kind (:func:`detect_format`); the reader's
        errors (file and line of any bad cell).
    """
    path = Path(path)
    if format != "auto" and format not in FORMATS:
        raise InputError(f"{path}: unknown format {format!r} (expected auto or one of {sorted(FORMATS)})")
    found = detect_format(path)
    if format != "auto" and format != found:
        raise InputError(
            f"{path}: the config says {FORMATS[format]} ({format}) but the file is a "
            f"{FORMATS[found]} ({found}); set the format to {found} or auto, or name the right file"
        )
    if found == "motive_csv":
        return read_motive_csv(path)
    if found == "qtm_tsv":
        return read_qtm_tsv(path)
    markers = read_nexus_csv(path) if found == "vicon_csv" else read_c3d(path)
    return MocapExport(path, found, float(markers.attrs["rate_hz"]), markers, None, {})


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

    Raises
    ------
    InputError
        File missing or of another kind (a Nexus Devices-only export, a TUM pose list: the
        message says what it is and what was expected); the reader's errors; an export
        without markers (a QTM 6D file: use ``mocap.bodies_from: system``); a configured
        marker missing from the file (the message lists the file's markers) or never seen.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    export = read_mocap(path, format)
    df = export.markers
    if not marker_names(df):
        solved = export.meta.get("body_markers")
        if solved is not None and marker_names(solved):
            log.warning("%s: no Marker columns; using the Rigid Body Marker (solved) positions", path)
            df = solved
        else:
            have = ", ".join(map(repr, export.body_names)) or "none"
            raise InputError(
                f"{path}: a {FORMATS[export.format]} without marker positions (its rigid bodies: "
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
            f"{path}: a {FORMATS[export.format]} with {n} markers and no rigid-body poses; "
            "bodies_from: system needs the system's own bodies (Motive: export Rigid Bodies; "
            "QTM: export 6DOF data as TSV). Use bodies_from: markers to fit the markers instead"
        )
    out = select_system_bodies(export.bodies, names, source=str(path))
    out.attrs["rate_hz"] = export.rate_hz
    return out


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
        ``bodies_from: system`` with a body lacking ``system_body``, or ``bodies_from: markers``
        with a body lacking ``names``.
    """
    out = {"format": "auto", "bodies_from": "markers", **(cfg.get("mocap") or {})}
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
