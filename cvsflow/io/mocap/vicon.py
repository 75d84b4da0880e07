"""Vicon exports: Nexus/Tracker 'Trajectories' CSV (read and write) and C3D (read).

Both give the wide marker table of :mod:`cvsflow.io.mocap.markers`. The entry point for any
motion-capture export is :func:`cvsflow.io.mocap.formats.read_markers`, which dispatches on the
file's content to these readers or to :mod:`cvsflow.io.mocap.optitrack` and :mod:`cvsflow.io.mocap.qualisys`.
"""

from __future__ import annotations

import logging
import struct
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError
from cvsflow.io.files import (
    atomic_output,
    check_frames,
    drop_cut_last_row,
    parse_numeric_block,
    read_text_lines,
)
from cvsflow.io.mocap.markers import (
    FileHead,
    MocapExport,
    MocapFormat,
    marker_columns,
    marker_names,
    marker_table,
    note_frame_count,
)

log = logging.getLogger(__name__)


def write_nexus_csv(df: pd.DataFrame, path, rate_hz: float, decimals: int = 4) -> None:
    """Write a marker table as a Vicon Nexus 'Trajectories' CSV (mm, CRLF, empty cells for gaps).

    Frames are written 1-based as Nexus does; ``Sub Frame`` is always 0.

    Parameters
    ----------
    df : DataFrame
        Wide marker table (``frame`` 0-based, ``{name}_{x,y,z}_m`` in metres in W, NaN gaps).
    path : str or Path
        Output CSV, written atomically.
    rate_hz : float
        Frame rate written on the rate line, Hz.
    decimals : int, default 4
        Decimals of the millimetre coordinates.

    Returns
    -------
    None
    """
    names = marker_names(df)
    n_cols = 2 + 3 * len(names)

    def pad(cells):
        return ",".join(cells + [""] * (n_cols - len(cells)))

    lines = [
        pad(["Trajectories"]),
        pad([f"{rate_hz:g}"]),
        ",".join(["", ""] + [c for n in names for c in (n, "", "")]),
        ",".join(["Frame", "Sub Frame"] + ["X", "Y", "Z"] * len(names)),
        ",".join(["", ""] + ["mm"] * (3 * len(names))),
    ]
    xyz_mm = df[[c for n in names for c in marker_columns(n)]].to_numpy(float) * 1000.0
    frames = df["frame"].to_numpy(int) + 1
    fmt = f"{{:.{decimals}f}}"
    for frame, row in zip(frames, xyz_mm, strict=True):
        cells = [str(frame), "0"] + ["" if np.isnan(v) else fmt.format(v) for v in row]
        lines.append(",".join(cells))
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write("\r\n".join(lines) + "\r\n")


# --------------------------------------------------------------------------- readers

_UNIT_TO_M = {"mm": 1e-3, "cm": 1e-2, "m": 1.0}


def _split(line: str) -> list[str]:
    return [c.strip() for c in line.split(",")]


def _strip_trailing(cells: list[str]) -> list[str]:
    end = len(cells)
    while end and cells[end - 1] == "":
        end -= 1
    return cells[:end]


def read_nexus_csv(path) -> pd.DataFrame:
    """Read a Vicon Nexus / Tracker 'Trajectories' CSV export into a marker table.

    Parameters
    ----------
    path : str or Path
        The CSV file: a ``Trajectories`` line, the rate (Hz) line, the ``Subject:Marker`` row,
        the ``Frame,Sub Frame,X,Y,Z,...`` row, the units row (mm, cm or m), then one row per
        frame with empty cells where a marker was not seen (``inf``, ``-inf`` and overflowing
        numbers such as ``1e999`` are gaps too: NaN, counted in a WARNING naming the first
        line and column). CRLF or LF line ends; rows may be
        padded with empty cells. Other blocks (``Devices``, ``Model Outputs``) are skipped.

    Returns
    -------
    markers : DataFrame
        Wide marker table (module docstring): ``frame`` 0-based (Nexus ``Frame`` - 1),
        ``t_s`` = frame / rate in s, ``{name}_{x,y,z}_m`` in metres in W, NaN in gaps.

    Raises
    ------
    InputError
        No Trajectories block, no rate line, a malformed header, an unknown unit, a row inside
        the block with fewer cells than the header, a non-numeric cell, frames not
        consecutive. The message names the file and the 1-based line number. A last row cut
        mid-row (a file cut short) is left out with a WARNING
        (:func:`cvsflow.io.mocap.markers.note_frame_count`).
    """
    path = Path(path)
    lines = read_text_lines(path, "CSV")
    start = next(
        (i for i, ln in enumerate(lines) if _split(ln)[0].lower() == "trajectories"), None
    )
    if start is None:
        raise InputError(
            f"{path}: no 'Trajectories' line found (expected a Vicon Nexus trajectories CSV)"
        )
    # 1-based line numbers of the header rows
    ln_rate, ln_names, ln_axes, ln_units = start + 2, start + 3, start + 4, start + 5
    if len(lines) < start + 5:
        raise InputError(
            f"{path}, line {len(lines)}: file ends inside the Trajectories header "
            "(expected rate, Subject:Marker, Frame/Sub Frame and units rows)"
        )
    rate_cells = _split(lines[start + 1])
    try:
        rate_hz = float(rate_cells[0])
    except ValueError:
        rate_hz = float("nan")
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise InputError(
            f"{path}, line {ln_rate}: no rate line after 'Trajectories' "
            f"(expected the frame rate in Hz, got {lines[start + 1][:40]!r})"
        )
    name_cells = _split(lines[start + 2])
    axis_cells = _strip_trailing(_split(lines[start + 3]))
    unit_cells = _split(lines[start + 4])
    if len(axis_cells) < 2 or axis_cells[0] != "Frame" or axis_cells[1] != "Sub Frame":
        raise InputError(
            f"{path}, line {ln_axes}: expected 'Frame,Sub Frame,X,Y,Z,...', "
            f"got {lines[start + 3][:40]!r}"
        )
    n_markers = (len(axis_cells) - 2) // 3
    if n_markers == 0 or len(axis_cells) != 2 + 3 * n_markers:
        raise InputError(
            f"{path}, line {ln_axes}: expected X,Y,Z triples after 'Frame,Sub Frame', "
            f"got {len(axis_cells) - 2} coordinate columns"
        )
    names = []
    for k in range(n_markers):
        c = 2 + 3 * k
        if axis_cells[c : c + 3] != ["X", "Y", "Z"]:
            raise InputError(
                f"{path}, line {ln_axes}, column {c + 1}: expected 'X,Y,Z', "
                f"got {','.join(axis_cells[c : c + 3])!r}"
            )
        name = name_cells[c] if c < len(name_cells) else ""
        if not name:
            raise InputError(
                f"{path}, line {ln_names}, column {c + 1}: empty marker name "
                "(expected Subject:Marker above each X,Y,Z triple)"
            )
        names.append(name)
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"{path}, line {ln_names}: duplicate marker names {dup}")
    scale = np.empty(3 * n_markers)
    for j in range(3 * n_markers):
        unit = unit_cells[2 + j] if 2 + j < len(unit_cells) else ""
        if unit not in _UNIT_TO_M:
            raise InputError(
                f"{path}, line {ln_units}, column {3 + j} ({names[j // 3]}): unknown unit "
                f"{unit!r} (expected one of {sorted(_UNIT_TO_M)})"
            )
        scale[j] = _UNIT_TO_M[unit]

    first = start + 5  # 0-based index of the first data line
    end = first
    while end < len(lines) and lines[end].strip(", \t"):
        end += 1
    n_cols = 2 + 3 * n_markers
    data_lines, cut = drop_cut_last_row(lines[first:end], n_cols)
    if not data_lines:
        raise InputError(f"{path}, line {first + 1}: no data rows after the units row")
    col_names = ["Frame", "Sub Frame"] + [f"{n}_{a}" for n in names for a in "XYZ"]
    values = parse_numeric_block(
        path, data_lines, first, n_cols, col_names,
        expected=f"Frame, Sub Frame and X,Y,Z for {n_markers} markers", pandas_na=True,
    )
    frames = values[:, 0]
    check_frames(path, frames, first, data_lines)
    coords = values[:, 2:]
    bad = np.isinf(coords)  # 'inf', '-inf', '1e999': not a position, a gap (NaN)
    if bad.any():
        i, j = (int(v[0]) for v in np.nonzero(bad))
        log.warning(
            "%s: %d non-finite coordinate cells (inf, -inf or overflow such as 1e999) read as "
            "gaps (NaN); the first at line %d, column %s_%s (%r)",
            path, int(bad.sum()), first + i + 1, names[j // 3], "XYZ"[j % 3],
            data_lines[i].split(",")[2 + j].strip(),
        )
        coords = np.where(bad, np.nan, coords)
    xyz_m = (coords * scale).reshape(len(values), n_markers, 3)
    markers = marker_table(frames.astype(np.int64) - 1, xyz_m, names, rate_hz)
    # Nexus states no frame count: only a last row cut mid-row shows a file cut short
    note_frame_count(markers, path, None, cut_line=first + len(data_lines) + 1 if cut else None)
    return markers


def read_c3d(path) -> pd.DataFrame:
    """Read the POINT data of a C3D file (through ezc3d) into a marker table.

    Parameters
    ----------
    path : str or Path
        A C3D file. POINT:UNITS (mm, cm or m) scales to metres; POINT:LABELS (and LABELS2,
        ... for long lists) name the markers; samples with a negative residual are gaps.

    Returns
    -------
    markers : DataFrame
        Wide marker table (module docstring); ``frame`` 0-based from the header's first frame
        (ezc3d counts from 0, so Nexus frame 1 is frame 0, as in the CSV).
        ``attrs["n_frames_stated"]``: the frames the file's header block states; a file cut
        short is read as far as it goes, with a WARNING naming both counts.

    Raises
    ------
    InputError
        File missing or unreadable by ezc3d, no POINT rate, unknown units, no markers.
    """
    import ezc3d

    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: file not found")
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises plain RuntimeError/IOError on a bad file
        raise InputError(f"{path}: not a readable C3D file ({exc})") from exc
    point = c3d["parameters"].get("POINT", {})
    rate = point.get("RATE", {}).get("value", [])
    rate_hz = float(rate[0]) if len(rate) else float(c3d["header"]["points"]["frame_rate"])
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise InputError(f"{path}: POINT:RATE missing or not positive (got {rate_hz})")
    units = point.get("UNITS", {}).get("value", ["mm"])
    unit = (units[0] if len(units) else "mm").strip()
    if unit not in _UNIT_TO_M:
        raise InputError(
            f"{path}: POINT:UNITS is {unit!r} (expected one of {sorted(_UNIT_TO_M)})"
        )
    labels = list(point.get("LABELS", {}).get("value", []))
    k = 2
    while f"LABELS{k}" in point:
        labels += list(point[f"LABELS{k}"]["value"])
        k += 1
    pts = np.asarray(c3d["data"]["points"], dtype=float)  # (4, n_markers, n_frames)
    n_markers = pts.shape[1]
    if n_markers == 0:
        raise InputError(f"{path}: no POINT markers in the file")
    names = [str(s).strip() for s in labels[:n_markers]]
    if len(names) < n_markers:
        raise InputError(
            f"{path}: POINT:LABELS has {len(names)} names for {n_markers} markers"
        )
    xyz = np.transpose(pts[:3], (2, 1, 0)) * _UNIT_TO_M[unit]  # (n_frames, n_markers, 3)
    if not np.isfinite(xyz).all():
        log.warning("%s: %d non-finite coordinates read as gaps (NaN)", path,
                    int((~np.isfinite(xyz)).sum()))
        xyz[~np.isfinite(xyz)] = np.nan
    residuals = c3d["data"].get("meta_points", {}).get("residuals")
    if residuals is not None and np.size(residuals):
        bad = np.asarray(residuals)[0].T < 0  # Vicon marks an unseen sample by residual -1
        xyz[bad] = np.nan
    first = int(c3d["header"]["points"]["first_frame"])
    frame0 = first + np.arange(xyz.shape[0])
    markers = marker_table(frame0, xyz, names, rate_hz)
    note_frame_count(markers, path, *_c3d_stated_frames(path, c3d))
    return markers


def _c3d_stated_frames(path, c3d) -> tuple[int | None, str]:
    """Frames the C3D's own header block states, and where (ezc3d rewrites its header to the
    frames it could read, so a file cut short reads as whole there)."""
    with open(path, "rb") as fh:
        head = fh.read(512)
        fh.seek(512 * (head[0] - 1) + 3)
        processor = fh.read(1)
    # processor type 84 Intel, 85 DEC: little-endian words; 86 MIPS: big-endian
    order = ">" if processor == b"\x56" else "<"
    first, last = struct.unpack(f"{order}HH", head[6:10])
    if last == 0xFFFF:  # the header's 16-bit count is full: long takes state it in TRIAL
        trial = c3d["parameters"].get("TRIAL", {})
        try:
            start, end = (trial[k]["value"] for k in ("ACTUAL_START_FIELD", "ACTUAL_END_FIELD"))
            first, last = int(start[0]) + 65536 * int(start[1]), int(end[0]) + 65536 * int(end[1])
        except (KeyError, IndexError):
            return None, ""
        return last - first + 1, "TRIAL:ACTUAL_START_FIELD..ACTUAL_END_FIELD"
    return last - first + 1, f"header frames {first}..{last}"



# --------------------------------------------------------------------------- the format registry

_NEXUS_BLOCKS = ("Devices", "Trajectories", "Model Outputs", "Segments", "Joints")


def _nexus_sections(path: Path) -> list[str]:
    """Names of the Nexus CSV blocks (a block name is a line of one word followed by the rate)."""
    names = []
    prev_blank = True
    with open(path, encoding="utf-8-sig", errors="replace") as fh:
        for line in fh:
            cell = line.split(",")[0].strip()
            rest = line.strip().strip(",").strip()
            if prev_blank and cell in _NEXUS_BLOCKS and rest == cell:
                names.append(cell)
            prev_blank = not line.strip(", \t\r\n")
    return names


def detect_nexus_csv(head: FileHead) -> str | None:
    """Why the file is a Nexus Trajectories CSV, or None; an InputError for a Nexus CSV without one.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None

    Raises
    ------
    InputError
        A Nexus CSV with only Devices (analog), Model Outputs, Segments or Joints blocks: no
        marker positions; the message says what to export instead.
    """
    if head.binary or not head.lines:
        return None
    cells = [ln.split(",")[0].strip().strip('"') for ln in head.lines]
    if "Trajectories" in cells:
        return "a Trajectories block"
    if cells[0] not in _NEXUS_BLOCKS:
        return None
    sections = _nexus_sections(head.path)
    if "Trajectories" in sections:
        return "a Trajectories block"
    rate = head.lines[1].split(",")[0].strip() if len(head.lines) > 1 else "?"
    raise InputError(
        f"{head.path}: a Vicon Nexus CSV with only the block(s) {', '.join(sections)} "
        f"({cells[0]} at {rate} Hz: analog, force-plate or EMG channels), no Trajectories "
        "block, so no marker positions. Expected the Trajectories (marker) export: in Nexus, "
        "Export CSV with 'Trajectories' ticked"
    )


def detect_c3d(head: FileHead) -> str | None:
    """Why the file is a C3D file (byte 2 of the header block is the parameter key 0x50), or None.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None
    """
    if len(head.raw) >= 512 and head.raw[1] == 0x50 and b"\x00" in head.raw[:512]:
        return "the C3D parameter key 0x50 in byte 2"
    return None


def _nexus_export(path) -> MocapExport:
    markers = read_nexus_csv(path)
    markers.attrs["format"] = "vicon_csv"
    return MocapExport(Path(path), "vicon_csv", float(markers.attrs["rate_hz"]), markers, None, {})


def _c3d_export(path) -> MocapExport:
    markers = read_c3d(path)
    markers.attrs["format"] = "c3d"
    return MocapExport(Path(path), "c3d", float(markers.attrs["rate_hz"]), markers, None, {})


NEXUS_CSV = MocapFormat("vicon_csv", "Vicon Nexus Trajectories CSV", "markers", detect_nexus_csv,
                        _nexus_export)  # fmt: skip
C3D = MocapFormat("c3d", "C3D", "markers", detect_c3d, _c3d_export)
