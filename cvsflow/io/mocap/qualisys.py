"""Qualisys QTM TSV exports: 3D markers and 6DOF bodies, old (QTM 2.x) and current layouts.

A QTM TSV starts with ``KEY<tab>value`` header lines (``NO_OF_FRAMES``, ``FREQUENCY``,
``DATA_INCLUDED 3D`` or ``6D``, ``MARKER_NAMES`` or ``BODY_NAMES``, ...; ``FILE_VERSION 2.0.0``
first in current exports). Then:

- **3D, current layout**: ``TRAJECTORY_TYPES``, a column row ``Frame Time <name> X <name> Y
  <name> Z ...`` and rows with the 1-based frame number and the time.
- **3D, old layout**: no column row, no Frame/Time columns: 3 values per marker per row.
- **6D, current layout**: a column row ``Frame Time <body> X Y Z <3 angles> Residual Rot[0]
  ... Rot[8]`` per body.
- **6D, old layout**: one label row `` X  Y  Z  Yaw  Pitch  Roll  Residual  Rot[0] ... Rot[8]``
  written once for all bodies; the data rows hold 16 values per body, bodies separated by an
  empty field (a double tab) and a trailing tab.

Positions and residuals are millimetres; ``Rot[0..8]`` is the body's rotation matrix in W in
column order (``Rot[0..2]`` the first column), so R = reshape(Rot, 3, 3).T. The Euler angles are
not read: their convention is a QTM setting, the matrix is not. Gaps: empty, ``NaN`` or ``NULL``
cells, a marker at exactly (0, 0, 0) (QTM's "not seen" in 3D exports), a body with residual -1
or an all-zero row (QTM's "not tracked" in 6D exports).

The old layouts are checked against real QTM exports (tests/unit/test_io_qualisys.py); the
current ones follow QTM's documented header and are located by their column labels (``<name>
X``, ``Rot[0]``), so extra columns are ignored; no public real export of the current 6D layout
was found to test against.
"""

from __future__ import annotations

import logging
import re
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
    system_bodies_table,
)

log = logging.getLogger(__name__)

#: The header keys QTM writes on a TSV's first line (FILE_VERSION, else NO_OF_FRAMES first).
_QTM_KEY = re.compile(r"^(?:FILE_VERSION|NO_OF_[A-Z]+|FREQUENCY|ANALOG_FREQUENCY|DESCRIPTION|"
                      r"TIME_STAMP|DATA_INCLUDED|MARKER_NAMES|BODY_NAMES)$")
_KEY = re.compile(r"^(?:[A-Z][A-Z0-9]*_[A-Z0-9_]+|FREQUENCY|DESCRIPTION|EVENT)$")
_NA = ("NaN", "nan", "NULL", "null", "-")
_MM = 1e-3
_ROT = [f"Rot[{k}]" for k in range(9)]


def read_qtm_tsv(path) -> MocapExport:
    """Read a Qualisys QTM TSV export (3D markers or 6DOF bodies).

    Parameters
    ----------
    path : str or Path
        The TSV (module docstring for the layouts).

    Returns
    -------
    MocapExport
        3D: ``markers`` in metres in QTM's world W, ``frame`` 0-based (QTM frame - 1),
        ``t_s`` = frame / FREQUENCY, ``bodies`` None. 6D: ``markers`` without marker columns,
        ``bodies`` one system body per BODY_NAMES entry (``fit_rms_m`` = QTM residual in
        metres, ``n_markers`` -1: the export does not say). ``meta``: the header values, the
        ``layout`` (``old`` / ``current``) and ``n_gap_samples`` (3D: marker samples per name
        that are gaps; 6D: untracked frames per body).

    Raises
    ------
    InputError
        Not a QTM TSV; no NO_OF_FRAMES or FREQUENCY header line (the message names the one
        missing); DATA_INCLUDED other than 3D/6D, or missing with no single MARKER_NAMES or
        BODY_NAMES line to tell which; header counts that disagree with the names or the
        columns; a short row; a non-numeric cell (file, line and column named); non-consecutive
        frames. Fewer rows than NO_OF_FRAMES (a file cut short, at a row boundary or mid-row)
        are read as far as they go with a WARNING naming both counts
        (:func:`cvsflow.io.mocap.markers.note_frame_count`).
    """
    path = Path(path)
    lines = read_text_lines(path, "TSV")
    header = {}
    i = 0
    while i < len(lines) and _KEY.match(lines[i].split("\t")[0]):
        cells = lines[i].split("\t")
        key = cells[0].strip()
        values = [c.strip() for c in cells[1:]]
        while values and values[-1] == "":
            values.pop()
        if key == "EVENT":
            header.setdefault("EVENTS", []).append(values)
        else:
            header[key] = values
        i += 1
    missing = [k for k in ("NO_OF_FRAMES", "FREQUENCY") if k not in header]
    if missing:
        raise InputError(
            f"{path}, lines 1-{i}: no {' and no '.join(missing)} header line (expected "
            f"{' and '.join(f'{k!r}<tab><value>' for k in missing)} among the header lines QTM "
            "writes; export with 'Include TSV header' ticked, or restore the line)"
        )
    rate_hz = _number(path, header, "FREQUENCY", lines)
    n_frames = int(_number(path, header, "NO_OF_FRAMES", lines))
    included = _data_included(path, header, i)
    meta = {k: (v[0] if len(v) == 1 else v) for k, v in header.items() if k != "EVENTS"}
    if included not in ("3D", "6D"):
        raise InputError(
            f"{path}, line {_line_of(lines, 'DATA_INCLUDED')}: DATA_INCLUDED {included!r}, "
            "expected 3D (markers) or 6D (6DOF bodies)"
        )
    labels = None
    if i < len(lines) and not _is_numeric_row(lines[i]):
        labels = [c.strip() for c in lines[i].split("\t")]
        i_labels = i
        i += 1
    first = i
    end = first
    while end < len(lines) and lines[end].strip("\t "):
        end += 1
    data_lines = lines[first:end]
    if included == "3D":
        export = _read_3d(path, header, meta, labels, data_lines, first, rate_hz, lines)
    else:
        export = _read_6d(path, header, meta, labels, data_lines, first, rate_hz,
                          i_labels if labels else None, lines)
    note_frame_count(export.markers, path, n_frames, "NO_OF_FRAMES", meta.pop("cut_line", None))
    if "DATA_INCLUDED" not in header:
        note = (f"{path}: no DATA_INCLUDED header line; read as {included}, as its "
                f"{'MARKER_NAMES' if included == '3D' else 'BODY_NAMES'} line says")
        log.warning(note)
        export.markers.attrs["warnings"] = [*export.markers.attrs.get("warnings", []), note]
    return export


def _data_included(path, header, n_header_lines):
    """3D or 6D: DATA_INCLUDED, or without it the kind its one names line gives."""
    if "DATA_INCLUDED" in header:
        return (header["DATA_INCLUDED"] or [""])[0]
    kinds = [k for k, key in (("3D", "MARKER_NAMES"), ("6D", "BODY_NAMES")) if key in header]
    if len(kinds) != 1:
        raise InputError(
            f"{path}, lines 1-{n_header_lines}: no DATA_INCLUDED header line (expected "
            "'DATA_INCLUDED<tab>3D' or '6D'), and no single MARKER_NAMES or BODY_NAMES line to "
            "tell which"
        )
    return kinds[0]


def _whole_rows(data_lines, n_cols, first, meta):
    """The data lines less a last row cut mid-row, whose line goes to ``meta["cut_line"]``."""
    whole, cut = drop_cut_last_row(data_lines, n_cols, sep="\t")
    meta["cut_line"] = first + len(whole) + 1 if cut else None
    return whole


def _number(path, header, key, lines):
    try:
        v = float(header[key][0])
    except (ValueError, IndexError):
        v = float("nan")
    if not np.isfinite(v) or v <= 0:
        raise InputError(
            f"{path}, line {_line_of(lines, key)}: {key} {header.get(key)!r}, expected a positive "
            "number (FREQUENCY 'EXT' exports have no fixed rate: export at a fixed frequency)"
        )
    return v


def _line_of(lines, key):
    return next((k + 1 for k, ln in enumerate(lines[:200]) if ln.startswith(key + "\t")), 1)


def _is_numeric_row(line):
    cell = line.split("\t")[0].strip()
    try:
        float(cell)
        return True
    except ValueError:
        return cell in _NA


def _frames_and_times(path, values, labels, first, data_lines, rate_hz):
    """0-based frames and t_s from the Frame column if there is one, else the row index."""
    if labels and labels[0] == "Frame":
        frames = values[:, 0]
        check_frames(path, frames, first, data_lines)
        frame = frames.astype(np.int64) - 1  # QTM counts from 1
    else:
        frame = np.arange(len(values), dtype=np.int64)
    return frame, frame / rate_hz


def _header_names(path, header, lines, kind, what):
    """The names of a ``{kind}_NAMES`` header line, checked against ``NO_OF_{kind}S``.

    ``kind`` is ``MARKER`` (3D, names must be unique) or ``BODY`` (6D); ``what`` names the
    export in messages."""
    key, count_key = f"{kind}_NAMES", f"NO_OF_{kind}S"
    names = header.get(key)
    if not names:
        raise InputError(f"{path}: {what} export without a {key} line (expected the {kind.lower()} names)")
    if count_key in header and int(float(header[count_key][0])) != len(names):
        raise InputError(
            f"{path}, line {_line_of(lines, key)}: {len(names)} {key}, {count_key} says "
            f"{header[count_key][0]}"
        )
    if kind == "MARKER" and len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"{path}, line {_line_of(lines, key)}: duplicate marker names {dup}")
    return names


def _read_3d(path, header, meta, labels, data_lines, first, rate_hz, lines):
    names = _header_names(path, header, lines, "MARKER", "3D")
    if labels:
        meta["layout"] = "current"
        where = {lab: j for j, lab in enumerate(labels)}
        cols = []
        for name in names:
            for axis in "XYZ":
                j = where.get(f"{name} {axis}")
                if j is None:
                    raise InputError(
                        f"{path}, line {first}: no column {name + ' ' + axis!r} (expected "
                        f"'<name> X/Y/Z' for every MARKER_NAMES entry)"
                    )
                cols.append(j)
        n_cols = max(cols + [1]) + 1
        col_names = (labels + [""] * n_cols)[:n_cols]
    else:
        meta["layout"] = "old"
        cols = list(range(3 * len(names)))
        n_cols = len(cols)
        col_names = [f"{n} {a}" for n in names for a in "XYZ"]
    data_lines = _whole_rows(data_lines, n_cols, first, meta)
    values = parse_numeric_block(path, data_lines, first, n_cols, col_names, sep="\t", na_values=_NA)
    frame, _ = _frames_and_times(path, values, labels, first, data_lines, rate_hz)
    xyz = values[:, cols].reshape(len(values), len(names), 3) * _MM
    zero = (xyz == 0.0).all(axis=2)  # QTM writes an unseen marker as 0, 0, 0
    xyz[zero] = np.nan
    gaps = ~np.isfinite(xyz).all(axis=2)
    meta["n_gap_samples"] = {n: int(gaps[:, k].sum()) for k, n in enumerate(names)}
    if gaps.any():
        log.info("%s: %d marker samples are gaps (empty, NaN or 0,0,0)", path, int(gaps.sum()))
    markers = marker_table(frame, xyz, names, rate_hz)
    markers.attrs["format"] = "qtm_tsv"
    return MocapExport(path, "qtm_tsv", rate_hz, markers, None, meta)


def _body_blocks(path, labels, n_bodies, data_lines, first, i_labels):
    """Column index of X and of Rot[0] per body, and the Frame/Time offset."""
    rot0 = [j for j, lab in enumerate(labels) if lab == "Rot[0]"]
    for j in rot0:
        ok = (j >= 7 and labels[j - 7].endswith("X") and labels[j - 6].endswith("Y")
              and labels[j - 5].endswith("Z") and labels[j - 1] == "Residual"
              and labels[j : j + 9] == _ROT)
        if not ok:
            raise InputError(
                f"{path}, line {i_labels + 1}: expected 'X Y Z <3 angles> Residual Rot[0] ... "
                f"Rot[8]' per body, got {labels[max(j - 7, 0) : j + 9]}"
            )
    if len(rot0) == n_bodies:
        return [j - 7 for j in rot0], "current"
    if len(rot0) == 1 and rot0[0] == 7 and labels[0].endswith("X"):
        # old layout: one label row for all bodies; stride 17 with the empty separator field
        n = len(data_lines[0].rstrip("\r\n").split("\t"))
        stride = 17 if n >= 17 * n_bodies - 1 else 16
        return [stride * k for k in range(n_bodies)], "old"
    raise InputError(
        f"{path}, line {i_labels + 1}: {len(rot0)} body column groups (Rot[0] ... Rot[8]) for "
        f"{n_bodies} BODY_NAMES"
    )


def _read_6d(path, header, meta, labels, data_lines, first, rate_hz, i_labels, lines):
    names = _header_names(path, header, lines, "BODY", "6D")
    if labels is None:
        raise InputError(
            f"{path}, line {first + 1}: no column label row (expected 'X Y Z ... Residual Rot[0] "
            "... Rot[8]' after BODY_NAMES)"
        )
    starts, layout = _body_blocks(path, labels, len(names), data_lines, first, i_labels)
    meta["layout"] = layout
    n_cols = starts[-1] + 16
    col_names = [""] * n_cols
    for name, s in zip(names, starts, strict=True):
        for k, lab in enumerate(["X", "Y", "Z", "angle 1", "angle 2", "angle 3", "Residual", *_ROT]):
            col_names[s + k] = f"{name} {lab}"
    if labels[0] == "Frame":
        col_names[0], col_names[1] = "Frame", "Time"
    data_lines = _whole_rows(data_lines, n_cols, first, meta)
    values = parse_numeric_block(path, data_lines, first, n_cols, col_names, sep="\t", na_values=_NA)
    frame, t_s = _frames_and_times(path, values, labels if layout == "current" else None, first,
                                   data_lines, rate_hz)
    parts = []
    meta["n_gap_samples"] = {}
    for name, s in zip(names, starts, strict=True):
        block = values[:, s : s + 16]
        p = block[:, 0:3] * _MM
        residual = block[:, 6]
        rot = block[:, 7:16]
        R = np.swapaxes(rot.reshape(-1, 3, 3), 1, 2)  # column order: Rot[0..2] is column 0
        lost = ((residual == -1.0) | (block == 0.0).all(axis=1)
                | ~np.isfinite(block[:, [0, 1, 2, 6, *range(7, 16)]]).all(axis=1))
        p[lost] = np.nan
        R[lost] = np.nan
        meta["n_gap_samples"][name] = int(lost.sum())
        parts.append(system_bodies_table(frame, t_s, name, R, p, np.where(lost, np.nan, residual * _MM),
                                         np.full(len(frame), -1, dtype=np.int64)))
    bodies = pd.concat(parts, ignore_index=True)
    bodies.attrs["rate_hz"] = rate_hz
    bodies.attrs["residual"] = "QTM 6DOF residual"
    markers = marker_table(frame, np.zeros((len(frame), 0, 3)), [], rate_hz)
    markers.attrs["format"] = "qtm_tsv"
    return MocapExport(path, "qtm_tsv", rate_hz, markers, bodies, meta)


# --------------------------------------------------------------------------- writer (tests, demos)


def write_qtm_tsv(path, markers=None, bodies=None, rate_hz=None, layout="current") -> None:
    """Write a QTM TSV as QTM does: 3D from a marker table, or 6D from a bodies table.

    Parameters
    ----------
    path : str or Path
    markers : DataFrame, optional
        Wide marker table (metres); gaps are written as 0, 0, 0 (old layout) or empty
        (current layout).
    bodies : DataFrame, optional
        Bodies table (``bodies.parquet`` columns); an invalid sample is written as zeros with
        residual -1. Exactly one of ``markers`` and ``bodies``.
    rate_hz : float, optional
        Default the table's ``attrs["rate_hz"]``.
    layout : {"current", "old"}
        ``current`` writes FILE_VERSION, TRAJECTORY_TYPES and a label row; ``old`` the bare
        header of older QTM versions.

    Returns
    -------
    None
        The file is written atomically; positions and residuals in mm, angles in degrees.

    Raises
    ------
    ValueError
        Both or neither of ``markers`` and ``bodies`` given.
    """
    if (markers is None) == (bodies is None):
        raise ValueError("write_qtm_tsv: give exactly one of markers and bodies")
    table = markers if markers is not None else bodies
    rate_hz = float(rate_hz or table.attrs["rate_hz"])
    head = ["FILE_VERSION\t2.0.0"] if layout == "current" else []
    if markers is not None:
        names = marker_names(markers)
        frame = markers["frame"].to_numpy(np.int64)
        data = markers[[c for n in names for c in marker_columns(n)]].to_numpy(float) / _MM
        if layout == "old":
            data = np.nan_to_num(data, nan=0.0)
        head += [f"NO_OF_FRAMES\t{len(frame)}", "NO_OF_CAMERAS\t8", f"NO_OF_MARKERS\t{len(names)}",
                 f"FREQUENCY\t{rate_hz:g}", "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0",
                 "DESCRIPTION\t--", "TIME_STAMP\t2026-01-01, 00:00:00\t0.0", "DATA_INCLUDED\t3D",
                 "MARKER_NAMES\t" + "\t".join(names)]
        if layout == "current":
            head += ["TRAJECTORY_TYPES\t" + "\t".join(["Measured"] * len(names)),
                     "Frame\tTime\t" + "\t".join(f"{n} {a}" for n in names for a in "XYZ")]
        sep_body = False
    else:
        names = list(pd.unique(bodies["body"]))
        frame = np.sort(pd.unique(bodies["frame"].to_numpy(np.int64)))
        blocks = []
        from scipy.spatial.transform import Rotation

        for name in names:
            sub = bodies[bodies["body"] == name].set_index("frame").reindex(frame)
            valid = sub["valid"].fillna(False).to_numpy(bool)
            q = sub[["qx", "qy", "qz", "qw"]].to_numpy(float, copy=True)
            q[~valid] = [0, 0, 0, 1]
            R = Rotation.from_quat(q).as_matrix()
            rpy = np.degrees(sub[["roll_rad", "pitch_rad", "yaw_rad"]].to_numpy(float))
            block = np.concatenate([
                sub[["x_m", "y_m", "z_m"]].to_numpy(float) / _MM, rpy,
                (sub["fit_rms_m"].to_numpy(float) / _MM)[:, None],
                np.swapaxes(R, 1, 2).reshape(-1, 9),  # column order
            ], axis=1)
            block[~valid] = 0.0
            block[~valid, 6] = -1.0
            blocks.append(block)
        head += [f"NO_OF_FRAMES\t{len(frame)}", "NO_OF_CAMERAS\t8", f"NO_OF_BODIES\t{len(names)}",
                 f"FREQUENCY\t{rate_hz:g}", "NO_OF_ANALOG\t0", "ANALOG_FREQUENCY\t0",
                 "DESCRIPTION\t--", "TIME_STAMP\t2026-01-01, 00:00:00\t0.0", "DATA_INCLUDED\t6D",
                 "BODY_NAMES\t" + "\t".join(names)]
        one = ["X", "Y", "Z", "Roll", "Pitch", "Yaw", "Residual", *_ROT]
        if layout == "current":
            head.append("Frame\tTime\t" + "\t".join(
                f"{n} {lab}" if lab in "XYZ" else lab for n in names for lab in one))
            data = np.concatenate(blocks, axis=1)
            sep_body = False
        else:
            head.append("\t".join(f" {lab}" for lab in one))
            data = blocks
            sep_body = True
    rows = []
    for i, f in enumerate(frame):
        if sep_body:
            cells = "\t\t".join("\t".join(f"{v:.5f}" for v in b[i]) for b in data) + "\t"
        else:
            cells = "\t".join("" if np.isnan(v) else f"{v:.5f}" for v in data[i])
        if layout == "current":
            cells = f"{int(f) + 1}\t{f / rate_hz:.5f}\t" + cells
        rows.append(cells)
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write("\r\n".join(head + rows) + "\r\n")


def detect(head: FileHead) -> str | None:
    """Why the file is a QTM TSV (its first line a QTM header key and a tab), or None.

    Any of QTM's header keys will do, so a file that lost its NO_OF_FRAMES line is still read
    as a QTM TSV, and the reader names the missing line.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None

    Raises
    ------
    InputError
        A QTM TSV of data other than 3D markers or 6D bodies (2D, analog, force): the message
        says what to export instead.
    """
    if head.binary or not head.lines:
        return None
    first = head.lines[0].strip()
    key = first.split("\t")[0].strip()
    if "\t" not in first or not _QTM_KEY.match(key):
        return None
    included = next((ln.split("\t")[1].strip() for ln in head.lines
                     if ln.startswith("DATA_INCLUDED\t")), None)  # fmt: skip
    if included in (None, "3D", "6D"):
        return f"its first key {key}"
    raise InputError(
        f"{head.path}: a Qualisys QTM TSV with DATA_INCLUDED {included!r} (expected 3D markers or "
        "6D bodies: export 3D data (.tsv) or 6DOF data (_6d.tsv) from QTM)"
    )


FORMAT = MocapFormat("qtm_tsv", "Qualisys QTM TSV", "markers", detect, read_qtm_tsv)
