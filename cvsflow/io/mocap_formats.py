"""Motion-capture exports of any make: format detection from the content, and one entry point.

Four formats are read into the same tables: Vicon Nexus 'Trajectories' CSV (``vicon_csv``),
C3D (``c3d``), OptiTrack Motive CSV (``motive_csv``, :mod:`cvsflow.io.optitrack`) and Qualisys
QTM TSV (``qtm_tsv``, :mod:`cvsflow.io.qualisys`). The *marker table* is the wide table of
:mod:`cvsflow.io.vicon` (``frame``, ``t_s``, ``{name}_{x,y,z}_m`` in metres in the system's world
frame W, NaN where unseen, ``attrs["rate_hz"]``, ``attrs["markers"]``). Where the export also
holds the system's own rigid-body solution (Motive rigid bodies, QTM 6DOF bodies), the *system
bodies table* has the ``bodies.parquet`` columns (:data:`cvsflow.mocap.BODY_COLUMNS`) with the
body named as in the export, ``fit_rms_m`` the system's own residual in metres (Motive: Mean
Marker Error; QTM: the 6DOF residual), ``n_markers`` the markers the system used (-1 when the
export does not say), ``n_filled`` 0.

The format is found from the first bytes of the file, never from its suffix alone, so a file
of the wrong kind (a Nexus Devices-only export, a TUM pose list, a TRC file) is named for what it
is, with what was expected.
"""

from __future__ import annotations

import io
import logging
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.errors import InputError

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
    """

    path: Path
    format: str
    rate_hz: float
    markers: pd.DataFrame
    bodies: pd.DataFrame | None = None
    meta: dict = field(default_factory=dict)

    @property
    def body_names(self) -> list[str]:
        """Names of the system's bodies, in file order (empty without bodies)."""
        if self.bodies is None:
            return []
        return list(pd.unique(self.bodies["body"]))


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
        from cvsflow.io.optitrack import read_motive_csv

        return read_motive_csv(path)
    if found == "qtm_tsv":
        from cvsflow.io.qualisys import read_qtm_tsv

        return read_qtm_tsv(path)
    from cvsflow.io.vicon import read_c3d, read_nexus_csv

    markers = read_nexus_csv(path) if found == "vicon_csv" else read_c3d(path)
    return MocapExport(path, found, float(markers.attrs["rate_hz"]), markers, None, {})


# --------------------------------------------------------------------------- shared parsing


def parse_numeric_block(path, lines, first, n_cols, column_names, sep=",", na_values=()) -> np.ndarray:
    """Parse data lines into a float array of shape (len(lines), n_cols); empty cells are NaN.

    Parameters
    ----------
    path : Path
        For messages.
    lines : list of str
        The data lines (no header).
    first : int
        0-based index in the file of ``lines[0]`` (messages give 1-based line numbers).
    n_cols : int
        Cells used per line; lines with fewer cells are an error (a cut file).
    column_names : list of str
        One name per used cell, for messages.
    sep : str
    na_values : sequence of str
        Extra cell texts meaning "not seen" (for example ``NaN`` or ``NULL``).

    Raises
    ------
    InputError
        A line with fewer than ``n_cols`` cells, or a non-numeric cell: file, 1-based line and
        column name.
    """
    if not lines:
        raise InputError(f"{path}, line {first + 1}: no data rows after the header")
    n_cells = np.fromiter((ln.count(sep) + 1 for ln in lines), int, len(lines))
    short = np.flatnonzero(n_cells < n_cols)
    if short.size:
        i = int(short[0])
        where = "the last row: file cut short" if i == len(lines) - 1 else "a truncated row"
        raise InputError(
            f"{path}, line {first + i + 1}: {n_cells[i]} cells, expected {n_cols} as the header "
            f"says; {where}"
        )
    block = "\n".join(lines)
    na = ["", *na_values]
    try:
        return pd.read_csv(
            io.StringIO(block), sep=sep, header=None, usecols=range(n_cols), dtype=np.float64,
            engine="c", skip_blank_lines=False, na_values=na, keep_default_na=False,
        ).to_numpy()
    except (ValueError, TypeError):
        pass
    cells = pd.read_csv(
        io.StringIO(block), sep=sep, header=None, usecols=range(n_cols), dtype=str,
        keep_default_na=False, skip_blank_lines=False,
    ).to_numpy()
    for i, row in enumerate(cells):
        for j, cell in enumerate(row):
            cell = cell.strip()
            if cell == "" or cell in na:
                continue
            try:
                float(cell)
            except ValueError:
                raise InputError(
                    f"{path}, line {first + i + 1}, column {column_names[j]}: non-numeric cell "
                    f"{cell!r} (expected a number, or an empty cell for a gap)"
                ) from None
    raise InputError(f"{path}, lines {first + 1}-{first + len(lines)}: unreadable data block")


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
    """
    from cvsflow.mocap import bodies_from_poses
    from cvsflow.transforms import make_T

    T = make_T(np.asarray(R_W_body, float), np.asarray(t_W_body_m, float))
    return bodies_from_poses(frame, t_s, body, T, residual_m, n_markers)


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
    from cvsflow.mocap import select_system_bodies

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
    from cvsflow.errors import ConfigError

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
