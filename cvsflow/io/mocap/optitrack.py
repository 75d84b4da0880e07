"""OptiTrack Motive CSV exports (format 1.2x): markers, rigid-body markers, rigid bodies.

Layout (Motive 2.x / 3.x, "Format Version" 1.21 to 1.25)::

    Format Version,1.23,Take Name,...,Export Frame Rate,120.000000,...,Rotation Type,Quaternion,
        Length Units,Meters,Coordinate Space,Global
    <blank>
    ,Type,Rigid Body,...,Rigid Body Marker,...,Marker,...
    ,Name,body,...,"body:Marker1",...,body:Marker1,...
    ,ID,...
    [,Parent,...]                                  (some versions)
    ,,Rotation,...,Position,...,Mean Marker Error,Position,...,Marker Quality,...
    Frame,Time (Seconds),X,Y,Z,W,X,Y,Z,,X,Y,Z,,...
    0,0.000000,...

Empty cells are gaps (a marker not seen, a rigid body not tracked). Column kinds read:

- ``Marker`` (labelled or ``Unlabeled NNNN``): measured positions -> the marker table;
- ``Rigid Body Marker`` / ``Bone Marker``: where the solved body puts its markers, with a
  ``Marker Quality`` (0..1) -> a second marker table (``body_markers``);
- ``Rigid Body`` / ``Bone``: the solved pose, Rotation X,Y,Z,W (scalar last, as scipy) and
  Position X,Y,Z, and ``Mean Marker Error`` -> the system bodies table.

Positions are scaled from the ``Length Units`` (Meters, Centimeters, Millimeters) to metres.
Only ``Rotation Type: Quaternion`` is read: Motive's Euler exports do not state whether the
order is intrinsic or extrinsic, so a wrong guess would give plausible but wrong rotations.
"""

from __future__ import annotations

import csv
import logging
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

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

_UNITS = {"meters": 1.0, "centimeters": 1e-2, "millimeters": 1e-3}
_POSE_TYPES = ("Rigid Body", "Bone")
_BODY_MARKER_TYPES = ("Rigid Body Marker", "Bone Marker")


def _row(line: str) -> list[str]:
    return next(csv.reader([line]))


def read_motive_csv(path) -> MocapExport:
    """Read an OptiTrack Motive CSV export.

    Parameters
    ----------
    path : str or Path
        The CSV (module docstring for the layout).

    Returns
    -------
    MocapExport
        ``markers``: wide marker table of the ``Marker`` columns, metres in Motive's world W,
        ``frame`` as in the file (0-based), ``t_s`` = frame / Export Frame Rate;
        ``bodies``: one system body per ``Rigid Body`` (``fit_rms_m`` = Mean Marker Error in
        metres, ``n_markers`` = its rigid-body markers with quality above 0, or -1), or None;
        ``meta``: the header pairs plus ``body_markers`` (the wide table of the rigid-body
        markers with ``{name}_quality`` columns, or None) and ``time_column_max_dev_s``.

    Raises
    ------
    InputError
        Not a Motive CSV, an unsupported format version, units or rotation type, a malformed
        header (rows Type/Name/.../Frame), a short row, a non-numeric cell, frames that are not
        consecutive, a rigid body without its seven pose columns. Messages name file and line.
    """
    path = Path(path)
    lines = read_text_lines(path, "CSV")
    meta_cells = _row(lines[0]) if lines else []
    if not meta_cells or meta_cells[0].strip() != "Format Version":
        raise InputError(
            f"{path}, line 1: expected 'Format Version,1.2x,...' (an OptiTrack Motive CSV), got "
            f"{(lines[0] if lines else '')[:50]!r}"
        )
    meta = {meta_cells[i].strip(): meta_cells[i + 1].strip() for i in range(0, len(meta_cells) - 1, 2)
            if meta_cells[i].strip()}
    version = meta.get("Format Version", "")
    if not version.startswith("1.2"):
        raise InputError(
            f"{path}, line 1: Format Version {version!r}; expected 1.2x (Motive 2.x / 3.x). "
            "Older 1.1 exports have another layout: re-export the take from a current Motive"
        )
    rate_txt = meta.get("Export Frame Rate") or meta.get("Capture Frame Rate", "")
    try:
        rate_hz = float(rate_txt)
    except ValueError:
        rate_hz = float("nan")
    if not np.isfinite(rate_hz) or rate_hz <= 0:
        raise InputError(
            f"{path}, line 1: Export Frame Rate {rate_txt!r}, expected a positive rate in Hz"
        )
    units = meta.get("Length Units", "")
    if units.lower() not in _UNITS:
        raise InputError(
            f"{path}, line 1: Length Units {units!r}; expected Meters, Centimeters or Millimeters"
        )
    scale = _UNITS[units.lower()]

    # header rows: find the 'Frame,Time...' row; the rows above it are labelled in column 2
    i_axis = next((i for i in range(1, min(len(lines), 20)) if _row(lines[i])[:1] == ["Frame"]), None)
    if i_axis is None:
        raise InputError(
            f"{path}: no 'Frame,Time (Seconds),...' row within the first 20 lines (expected the "
            "Type, Name, ID, kind and axis header rows of a Motive CSV)"
        )
    labelled = {}
    kinds = None
    for i in range(1, i_axis):
        cells = _row(lines[i]) if lines[i].strip() else []
        if not cells:
            continue
        label = cells[1].strip() if len(cells) > 1 else ""
        if label:
            labelled[label] = (i, cells)
        else:
            kinds = (i, cells)
    for need in ("Type", "Name"):
        if need not in labelled:
            raise InputError(
                f"{path}, lines 2-{i_axis}: no ',{need},...' header row (expected Type, Name and "
                "ID rows above the axis row)"
            )
    axes = [c.strip() for c in _row(lines[i_axis])]
    while axes and axes[-1] == "":
        axes.pop()
    n_cols = len(axes)
    types = _pad(labelled["Type"][1], n_cols)
    names = _pad(labelled["Name"][1], n_cols)
    kind = _pad(kinds[1], n_cols) if kinds else [""] * n_cols

    rot_type = meta.get("Rotation Type", "Quaternion")
    has_pose = any(t in _POSE_TYPES for t in types[2:])
    if has_pose and rot_type != "Quaternion":
        raise InputError(
            f"{path}, line 1: Rotation Type {rot_type!r}; expected Quaternion (export again with "
            "Rotation Type: Quaternion; Motive's Euler orders are ambiguous)"
        )

    first = i_axis + 1
    end = first
    while end < len(lines) and lines[end].strip(", \t"):
        end += 1
    data_lines, cut = drop_cut_last_row(lines[first:end], n_cols)
    col_names = [
        "Frame" if j == 0 else "Time" if j == 1 else f"{names[j]} {kind[j]} {axes[j]}".replace("  ", " ")
        for j in range(n_cols)
    ]
    values = parse_numeric_block(path, data_lines, first, n_cols, col_names)
    frames = values[:, 0]
    check_frames(path, frames, first, data_lines)
    frame = frames.astype(np.int64)
    t_s = frame / rate_hz
    dev = float(np.nanmax(np.abs(values[:, 1] - t_s))) if len(values) else 0.0
    # Motive rounds the time column (1 ms in some exports): frame / rate is the exact clock
    if dev > max(2e-3, 0.5 / rate_hz):
        log.warning("%s: the Time column departs from frame / %g Hz by up to %.4g s; using frame / rate",
                    path, rate_hz, dev)
    meta["time_column_max_dev_s"] = dev

    groups = _groups(types, names, kind, axes, n_cols)
    markers = _wide(groups, "Marker", values, frame, rate_hz, scale, path, labelled["Name"][0])
    body_markers = None
    if any(g[0] in _BODY_MARKER_TYPES for g in groups):
        body_markers = _wide(groups, _BODY_MARKER_TYPES, values, frame, rate_hz, scale, path,
                             labelled["Name"][0])
    meta["body_markers"] = body_markers
    bodies = _bodies(groups, values, frame, t_s, scale, path, i_axis, body_markers)
    if bodies is not None:
        bodies.attrs["rate_hz"] = rate_hz
        bodies.attrs["residual"] = "Motive Mean Marker Error"
    markers.attrs["format"] = "motive_csv"
    stated = meta.get("Total Exported Frames", "")
    note_frame_count(markers, path, int(stated) if stated.isdigit() else None,
                     "Total Exported Frames", first + len(data_lines) + 1 if cut else None)
    return MocapExport(path, "motive_csv", rate_hz, markers, bodies, meta)


def _pad(cells, n):
    cells = [c.strip() for c in cells][:n]
    return cells + [""] * (n - len(cells))


def _groups(types, names, kind, axes, n_cols):
    """(type, name, {(kind, axis): column}) per object, in file order."""
    out = {}
    order = []
    for j in range(2, n_cols):
        key = (types[j], names[j])
        if key not in out:
            out[key] = {}
            order.append(key)
        out[key][(kind[j], axes[j])] = j
    return [(t, n, out[(t, n)]) for t, n in order]


def _wide(groups, which, values, frame, rate_hz, scale, path, ln_names):
    """Wide marker table of the groups of the given type(s), with quality columns if any."""
    which = (which,) if isinstance(which, str) else which
    sel = [(n, cols) for t, n, cols in groups if t in which]
    names = [n for n, _ in sel]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"{path}, line {ln_names + 1}: duplicate {which[0]} names {dup}")
    xyz = np.full((len(frame), len(sel), 3), np.nan)
    quality = {}
    for k, (name, cols) in enumerate(sel):
        for a, axis in enumerate("XYZ"):
            j = cols.get(("Position", axis))
            if j is None:
                raise InputError(
                    f"{path}, line {ln_names + 1}: {which[0]} {name!r} has no Position {axis} column"
                )
            xyz[:, k, a] = values[:, j] * scale
        jq = cols.get(("Marker Quality", ""))
        if jq is not None:
            quality[f"{name}_quality"] = values[:, jq]
    df = marker_table(frame, xyz, names, rate_hz)
    if quality:
        df = pd.concat([df, pd.DataFrame(quality, index=df.index)], axis=1)
        df.attrs["rate_hz"] = float(rate_hz)
        df.attrs["markers"] = names
    return df


def _bodies(groups, values, frame, t_s, scale, path, i_axis, body_markers):
    parts = []
    for typ, name, cols in groups:
        if typ not in _POSE_TYPES:
            continue
        need = [("Rotation", a) for a in "XYZW"] + [("Position", a) for a in "XYZ"]
        missing = [f"{k} {a}" for k, a in need if (k, a) not in cols]
        if missing:
            raise InputError(
                f"{path}, line {i_axis + 1}: {typ} {name!r} lacks the column(s) {missing} "
                "(expected Rotation X,Y,Z,W and Position X,Y,Z)"
            )
        q = values[:, [cols[("Rotation", a)] for a in "XYZW"]]
        p = values[:, [cols[("Position", a)] for a in "XYZ"]] * scale
        ok = np.isfinite(q).all(axis=1) & np.isfinite(p).all(axis=1)
        norm = np.linalg.norm(q, axis=1)
        bad = ok & (np.abs(norm - 1.0) > 1e-2)
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            raise InputError(
                f"{path}, line {i_axis + 2 + i}: {typ} {name!r} quaternion has norm {norm[i]:.4g} "
                "(expected a unit quaternion X,Y,Z,W)"
            )
        R = np.full((len(frame), 3, 3), np.nan)
        if ok.any():
            R[ok] = Rotation.from_quat(q[ok]).as_matrix()
        j_err = cols.get(("Mean Marker Error", ""))
        residual = values[:, j_err] * scale if j_err is not None else np.full(len(frame), np.nan)
        n_markers = np.full(len(frame), -1, dtype=np.int64)
        if body_markers is not None:
            qcols = [c for c in body_markers.columns
                     if c.endswith("_quality") and c.startswith(f"{name}:")]
            if qcols:
                n_markers = (np.nan_to_num(body_markers[qcols].to_numpy(float)) > 0).sum(axis=1)
        parts.append(system_bodies_table(frame, t_s, name, R, np.where(ok[:, None], p, np.nan),
                                         residual, n_markers))
    if not parts:
        return None
    return pd.concat(parts, ignore_index=True)


# --------------------------------------------------------------------------- writer (tests, demos)


def write_motive_csv(path, markers, bodies=None, rate_hz=None, units="Meters", take="cvsflow") -> None:
    """Write a Motive CSV (format 1.23) from a marker table and optional bodies, as Motive does.

    Parameters
    ----------
    path : str or Path
    markers : DataFrame
        Wide marker table (metres); written as ``Marker`` columns.
    bodies : DataFrame, optional
        Bodies table (``bodies.parquet`` columns); each body becomes a ``Rigid Body`` with
        Rotation X,Y,Z,W, Position X,Y,Z and Mean Marker Error (from ``fit_rms_m``); invalid
        samples are empty cells.
    rate_hz : float, optional
        Default ``markers.attrs["rate_hz"]``.
    units : {"Meters", "Centimeters", "Millimeters"}
        Length Units of the file; positions are scaled from metres to them.
    take : str
        Take Name written in the first header line.

    Returns
    -------
    None
        The file is written atomically (CRLF line ends); ``Time`` = frame / rate_hz in s.
    """
    rate_hz = float(rate_hz or markers.attrs["rate_hz"])
    k = 1.0 / _UNITS[units.lower()]
    names = marker_names(markers)
    n = len(markers)
    frame = markers["frame"].to_numpy(np.int64)
    types, nm, kinds, axes, blocks = [], [], [], [], []
    body_list = list(pd.unique(bodies["body"])) if bodies is not None else []
    for body in body_list:
        sub = bodies[bodies["body"] == body].set_index("frame").reindex(frame)
        cols = sub[["qx", "qy", "qz", "qw", "x_m", "y_m", "z_m", "fit_rms_m"]].to_numpy(float, copy=True)
        cols[:, 4:] *= k
        cols[~sub["valid"].fillna(False).to_numpy(bool)] = np.nan
        types += ["Rigid Body"] * 8
        nm += [body] * 8
        kinds += ["Rotation"] * 4 + ["Position"] * 3 + ["Mean Marker Error"]
        axes += ["X", "Y", "Z", "W", "X", "Y", "Z", ""]
        blocks.append(cols)
    for name in names:
        types += ["Marker"] * 3
        nm += [name] * 3
        kinds += ["Position"] * 3
        axes += ["X", "Y", "Z"]
        blocks.append(markers[marker_columns(name)].to_numpy(float) * k)
    data = np.concatenate(blocks, axis=1) if blocks else np.zeros((n, 0))
    head = [
        f"Format Version,1.23,Take Name,{take},Take Notes,,Capture Frame Rate,{rate_hz:.6f},"
        f"Export Frame Rate,{rate_hz:.6f},Capture Start Time,2026-01-01 00.00.00.000 ,"
        f"Total Frames in Take,{n},Total Exported Frames,{n},Rotation Type,Quaternion,"
        f"Length Units,{units},Coordinate Space,Global",
        "",
        ",Type," + ",".join(types),
        ",Name," + ",".join(nm),
        ",ID," + ",".join(["1"] * len(types)),
        ",," + ",".join(kinds),
        "Frame,Time (Seconds)," + ",".join(axes),
    ]
    rows = []
    for f, row in zip(frame, data, strict=True):
        cells = [str(int(f)), f"{f / rate_hz:.6f}"] + ["" if np.isnan(v) else f"{v:.6f}" for v in row]
        rows.append(",".join(cells))
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write("\r\n".join(head + rows) + "\r\n")


def detect(head: FileHead) -> str | None:
    """Why the file is a Motive CSV (its first line starts ``Format Version,``), or None.

    Parameters
    ----------
    head : FileHead

    Returns
    -------
    str or None
    """
    first = head.lines[0].strip() if head.lines and not head.binary else ""
    if first.startswith("Format Version,") or first.startswith('"Format Version",'):
        return "its first line starts 'Format Version,'"
    return None


FORMAT = MocapFormat("motive_csv", "OptiTrack Motive CSV", "markers", detect, read_motive_csv)
