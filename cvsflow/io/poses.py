"""Pose lists: one pose of a carrier (robot end-effector, marker body) per still.

Formats
-------
- ``visp``: ViSP's ``vpPoseVector`` YAML (``vpPoseVector::saveYAML``)::

      rows: 6
      cols: 1
      data:
        - [tx]
        ...
        - [tuz]

  translation in metres then the theta-u rotation vector (axis times angle, radians; the same
  as a Rodrigues vector). One file per pose, or ``rows: N`` / ``cols: 6`` for N poses.
- ``tum``, ``asl``, ``eth``: the pose streams of :mod:`cvsflow.io.mocap` (TUM ``t x y z qx qy
  qz qw``; an ASL/EuRoC CSV with a header naming the columns, times in ns; ETH's ``t, x, y,
  z, qx, qy, qz, qw``), read in file order with every row kept
  (:func:`cvsflow.io.mocap.formats.read_pose_stream` with ``in_time_order=False``).
- ``csv``: a CSV with a header whose columns and units are declared (time/position/quaternion
  or Euler roll-pitch-yaw with R = Rz(yaw) Ry(pitch) Rx(roll), m/cm/mm, deg/rad), read by
  :func:`cvsflow.io.flightlog.read_csv_log`; the spec may add ``name_col``, a column naming
  the still of each row.

Every reader returns a *pose table*: one row per pose, columns ``name`` (what pairs the pose
with a still: the file stem for ``visp``, the ``name_col`` cell for ``csv``, else empty),
``t_s`` (NaN when the format has no time), ``t_ns`` (nullable Int64: the exact time where the
format writes one as a decimal, ``<NA>`` for ``visp`` and ``csv``), ``x_m y_m z_m`` (metres),
``qx qy qz qw`` (scalar-last unit quaternion), ``pos_valid``, ``rot_valid`` and ``origin``
("file, line n"), in file order. The pose is the carrier X in the pose source's world W,
``T_W_X``.
"""

from __future__ import annotations

import glob
import logging
import re
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf
from cvsflow.io.mocap.formats import BY_KEY, read_pose_stream
from cvsflow.io.mocap.markers import read_head

log = logging.getLogger(__name__)

#: The stream formats a pose list may be (read by :mod:`cvsflow.io.mocap`).
STREAM_POSE_FORMATS = ("tum", "asl", "eth")
POSE_FORMATS = ("visp", *STREAM_POSE_FORMATS, "csv")
POSE_TABLE_COLUMNS = ["name", "t_s", "t_ns", "x_m", "y_m", "z_m", "qx", "qy", "qz", "qw",
                      "pos_valid", "rot_valid", "origin"]  # fmt: skip


def _table(names, t_s, p_m, q_xyzw, origins, pos_valid=True, rot_valid=True, t_ns=None) -> pd.DataFrame:
    p = np.asarray(p_m, float).reshape(-1, 3)
    q = np.asarray(q_xyzw, float).reshape(-1, 4)
    n = len(p)
    t_ns = pd.array([pd.NA] * n if t_ns is None else np.asarray(t_ns, np.int64), dtype="Int64")
    return pd.DataFrame(
        {
            "name": list(names), "t_s": np.broadcast_to(np.asarray(t_s, float), n).copy(),
            "t_ns": t_ns,
            "x_m": p[:, 0], "y_m": p[:, 1], "z_m": p[:, 2],
            "qx": q[:, 0], "qy": q[:, 1], "qz": q[:, 2], "qw": q[:, 3],
            "pos_valid": np.broadcast_to(np.asarray(pos_valid, bool), n).copy(),
            "rot_valid": np.broadcast_to(np.asarray(rot_valid, bool), n).copy(),
            "origin": list(origins),
        }
    )[POSE_TABLE_COLUMNS]  # fmt: skip


def pose_table_T(table: pd.DataFrame) -> np.ndarray:
    """The poses of a pose table as transforms ``T_W_X``, shape (N, 4, 4); NaN where invalid.

    Parameters
    ----------
    table : DataFrame
        Pose table (``x_m, y_m, z_m`` metres, ``qx..qw`` scalar-last, ``pos_valid``,
        ``rot_valid``).

    Returns
    -------
    T_W_X : ndarray, shape (N, 4, 4)
        Homogeneous transforms, metres; all-NaN where the position or rotation is not valid.
    """
    q = table[["qx", "qy", "qz", "qw"]].to_numpy(float)
    p = table[["x_m", "y_m", "z_m"]].to_numpy(float)
    ok = table["pos_valid"].to_numpy(bool) & table["rot_valid"].to_numpy(bool)
    T = np.full((len(table), 4, 4), np.nan)
    if ok.any():
        T[ok] = tf.make_T(tf.R_from_quat(q[ok]), p[ok])
    return T


# --------------------------------------------------------------------------------------------
# ViSP vpPoseVector
# --------------------------------------------------------------------------------------------


def T_from_pose_vector(pose6) -> np.ndarray:
    """Transforms from ViSP pose vectors ``[tx, ty, tz, tux, tuy, tuz]`` (m, rad), (..., 6).

    Parameters
    ----------
    pose6 : array_like, shape (..., 6)
        Translation (m) then the theta-u rotation vector (rad, = Rodrigues vector).

    Returns
    -------
    T : ndarray, shape (..., 4, 4)
        The transforms the vectors encode (for a ViSP ``cMo``, ``T_C_O``).
    """
    pose6 = np.asarray(pose6, float)
    return tf.make_T(tf.R_from_rvec(pose6[..., 3:6]), pose6[..., :3])


def _yaml_value(node, key):
    """The value node of ``key`` in a YAML mapping node, or None."""
    for k, v in node.value:
        if isinstance(k, yaml.ScalarNode) and k.value == key:
            return v
    return None


def _yaml_int(path, node, key):
    v = _yaml_value(node, key)
    if v is None:
        raise InputError(f"{path}: key {key!r} missing; expected a vpPoseVector (rows, cols, data)")
    try:
        return int(v.value)
    except (TypeError, ValueError):
        raise InputError(
            f"{path}, line {v.start_mark.line + 1}: {key} = {v.value!r}; expected an integer"
        ) from None


def read_visp_pose_vector(path) -> np.ndarray:
    """The pose vector(s) of a ViSP ``vpPoseVector`` YAML file.

    Parameters
    ----------
    path : str or Path
        ``rows: 6, cols: 1`` (one pose, ViSP's own layout) or ``rows: N, cols: 6`` (N poses),
        ``data`` a list of rows.

    Returns
    -------
    pose6 : ndarray, shape (N, 6)
        ``[tx, ty, tz, tux, tuy, tuz]``: metres, then theta-u radians.

    Raises
    ------
    InputError
        A missing or malformed file, a shape other than 6x1 or Nx6, rows and data disagreeing,
        or a cell that is not a number (the message names the line).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found (expected a ViSP vpPoseVector YAML file)")
    try:
        root = yaml.compose(path.read_text())
    except yaml.YAMLError as exc:
        raise InputError(f"{path}: not valid YAML ({exc})") from exc
    if not isinstance(root, yaml.MappingNode):
        raise InputError(f"{path}: expected a YAML mapping with rows, cols and data (vpPoseVector)")
    rows, cols = _yaml_int(path, root, "rows"), _yaml_int(path, root, "cols")
    if (rows, cols) != (6, 1) and cols != 6:
        raise InputError(
            f"{path}: rows: {rows}, cols: {cols}; expected a vpPoseVector, rows: 6 and cols: 1 "
            "(tx ty tz tux tuy tuz), or N rows of 6"
        )
    data = _yaml_value(root, "data")
    if not isinstance(data, yaml.SequenceNode):
        raise InputError(f"{path}: 'data' missing or not a list; expected {rows} rows of {cols}")
    if len(data.value) != rows:
        raise InputError(
            f"{path}, line {data.start_mark.line + 1}: data has {len(data.value)} rows; "
            f"expected {rows} (rows: {rows})"
        )
    cells = []
    for row in data.value:
        line = row.start_mark.line + 1
        items = row.value if isinstance(row, yaml.SequenceNode) else [row]
        if len(items) != cols or not all(isinstance(c, yaml.ScalarNode) for c in items):
            raise InputError(f"{path}, line {line}: row has {len(items)} values; expected {cols}")
        for c in items:
            try:
                v = float(c.value)
            except ValueError:
                raise InputError(
                    f"{path}, line {c.start_mark.line + 1}: {c.value!r} is not a number "
                    "(expected tx ty tz in m, tux tuy tuz in rad)"
                ) from None
            if not np.isfinite(v):
                raise InputError(f"{path}, line {c.start_mark.line + 1}: {c.value!r} is not finite")
            cells.append(v)
    return np.asarray(cells, float).reshape(-1, 6) if cols == 6 else np.asarray(cells).reshape(1, 6)


def read_visp_poses(paths) -> pd.DataFrame:
    """Pose table of ViSP pose-vector files (each may hold one or more poses), in the given order.

    The ``name`` of a pose is its file's stem (with ``#k`` appended when a file holds several).

    Parameters
    ----------
    paths : iterable of str or Path
        The vpPoseVector YAML files, in the order wanted.

    Returns
    -------
    poses : DataFrame
        Pose table (module docstring): ``name, t_s, x_m, y_m, z_m, qx, qy, qz, qw,
        pos_valid, rot_valid, origin``, T_W_X in metres, scalar-last quaternion;
        ``t_s`` NaN (the format has no time), every pose valid.

    Raises
    ------
    InputError
        No files, or a file that is not a vpPoseVector (file named).
    """
    frames = []
    for path in map(Path, paths):
        pose6 = read_visp_pose_vector(path)
        T = T_from_pose_vector(pose6)
        names = [path.stem] if len(pose6) == 1 else [f"{path.stem}#{k}" for k in range(len(pose6))]
        frames.append(
            _table(names, np.nan, T[:, :3, 3], tf.quat_from_R(T[:, :3, :3]),
                   [f"{path}" if len(pose6) == 1 else f"{path}, pose {k}" for k in range(len(pose6))])
        )  # fmt: skip
    if not frames:
        raise InputError("ViSP poses: no files given")
    return pd.concat(frames, ignore_index=True)


# --------------------------------------------------------------------------------------------
# TUM and declared CSV (the flight-log readers, re-expressed as pose tables)
# --------------------------------------------------------------------------------------------


def _file_order(t_file_s: np.ndarray) -> np.ndarray:
    """Indices that put rows sorted stably by time back into file order."""
    order = np.argsort(t_file_s, kind="stable")
    back = np.empty_like(order)
    back[order] = np.arange(len(order))
    return back


def read_stream_poses(path, fmt: str = "tum") -> pd.DataFrame:
    """Pose table of a pose-stream file (TUM, ASL or ETH), in file order, every row kept.

    Parameters
    ----------
    path : str or Path
        The file.
    fmt : {"tum", "asl", "eth", "auto"}
        Its format (:func:`cvsflow.io.mocap.formats.read_pose_stream`).

    Returns
    -------
    poses : DataFrame
        Pose table (module docstring): ``name`` empty, ``t_s`` and exact ``t_ns``, T_W_X in
        metres, scalar-last quaternion, ``origin`` "file, line n".

    Raises
    ------
    InputError
        As the stream readers (the bad line named; a format the content contradicts named).
    """
    path = Path(path)
    s = read_pose_stream(path, fmt, in_time_order=False, given_by="the pose format")
    return _table([""] * len(s), s["t_s"], s[["x_m", "y_m", "z_m"]], s[["qx", "qy", "qz", "qw"]],
                  [f"{path}, line {n}" for n in s["line"]], t_ns=s["t_ns"])  # fmt: skip


def read_tum_poses(path) -> pd.DataFrame:
    """Pose table of a TUM file (``timestamp tx ty tz qx qy qz qw``), in file order.

    Parameters
    ----------
    path : str or Path
        The TUM file.

    Returns
    -------
    poses : DataFrame
        :func:`read_stream_poses` with ``fmt="tum"``.

    Raises
    ------
    InputError
        As :func:`read_stream_poses`.
    """
    return read_stream_poses(path, "tum")


def read_csv_poses(path, spec: dict) -> pd.DataFrame:
    """Pose table of a CSV with declared columns and units, in file order.

    Parameters
    ----------
    path : str or Path
    spec : dict
        The keys of :func:`cvsflow.io.flightlog.read_csv_log` (``time_col``, ``time_unit``,
        ``pos_cols``, ``pos_unit``, ``rot`` = quat_xyzw / quat_wxyz / euler_rpy, ``rot_cols``,
        ``angle_unit``, ...) plus optional ``name_col``: the column naming each row's still.

    Returns
    -------
    poses : DataFrame
        Pose table (module docstring): ``name, t_s, x_m, y_m, z_m, qx, qy, qz, qw,
        pos_valid, rot_valid, origin``, T_W_X in metres, scalar-last quaternion;
        ``name`` the ``name_col`` cell (empty without one), ``origin`` "file, line n"
        (line 2 is the first data row).

    Raises
    ------
    InputError
        As ``read_csv_log`` (row and column of a bad cell named), or ``name_col`` absent.
    """
    from cvsflow.io.flightlog import read_csv_log

    path = Path(path)
    spec = dict(spec or {})
    name_col = spec.pop("name_col", None)
    traj = read_csv_log(path, spec)  # sorted by time (stable); file order is restored below
    raw = pd.read_csv(path, skipinitialspace=True)
    raw.columns = [str(c).strip() for c in raw.columns]
    t_col = spec.get("time_col", "t")
    t_file = pd.to_numeric(raw[t_col]).to_numpy(float)
    traj = traj.iloc[_file_order(t_file)]
    if name_col is not None and name_col not in raw.columns:
        raise InputError(f"{path}: name_col {name_col!r} not in the header {list(raw.columns)}")
    names = raw[name_col].astype(str).str.strip().tolist() if name_col else [""] * len(raw)
    return _table(names, traj["t_s"], traj[["x_m", "y_m", "z_m"]], traj[["qx", "qy", "qz", "qw"]],
                  [f"{path}, line {i + 2}" for i in range(len(raw))], traj["pos_valid"],
                  traj["rot_valid"])  # fmt: skip


# --------------------------------------------------------------------------------------------
# one entry point
# --------------------------------------------------------------------------------------------


def natural_key(text: str):
    """Sort key that orders embedded integers by value (image-2 before image-10).

    Parameters
    ----------
    text : str
        The name to sort.

    Returns
    -------
    list of int and str
        The text split into runs of digits (as int) and the rest (lower-cased).
    """
    return [int(s) if s.isdigit() else s.lower() for s in re.split(r"(\d+)", str(text))]


def expand_pose_glob(pattern) -> list[Path]:
    """Files matching ``pattern`` (a glob, or one path), in natural order; an error if none.

    Parameters
    ----------
    pattern : str or Path
        A glob pattern or a single file path.

    Returns
    -------
    list of Path
        The matches, sorted by :func:`natural_key` of their names; never empty.

    Raises
    ------
    InputError
        Nothing matches.
    """
    paths = sorted((Path(p) for p in glob.glob(str(pattern))), key=lambda p: natural_key(p.name))
    if not paths:
        raise InputError(f"{pattern}: no pose file matches")
    return paths


def sniff_pose_format(path) -> str | None:
    """``visp``, ``tum``, ``asl``, ``eth`` or ``csv`` when the start of a file looks like one, else None.

    Parameters
    ----------
    path : str or Path
        The file; its first 64 KiB are looked at.

    Returns
    -------
    str or None
        ``visp`` (rows/cols/data keys); a pose stream whose columns are known without a spec
        (the stream formats' own detection: TUM rows of 8 numbers, an ASL header naming every
        column, ETH rows of 8 comma-separated numbers); ``csv`` (another comma-separated header
        then a comma-separated line); None when the file cannot be read, is empty or matches
        none.
    """
    try:
        head = read_head(path, "a pose file")
    except InputError:
        return None
    body = [ln.strip() for ln in head.lines if ln.strip() and not ln.lstrip().startswith("#")]
    if not body or head.binary:
        return None
    keys = {ln.split(":")[0].strip() for ln in body if ":" in ln}
    if {"rows", "cols", "data"} <= keys:
        return "visp"
    for key in STREAM_POSE_FORMATS:
        if BY_KEY[key].detect(head):
            lay = head.memo.get("stream_layout")
            if key != "asl" or (lay is not None and lay.names_all_roles):
                return key
    if "," in body[0] and len(body) > 1 and "," in body[1]:
        return "csv"
    return None


def read_pose_list(pattern, fmt: str, csv_spec: dict | None = None) -> pd.DataFrame:
    """Pose table of the files matching ``pattern`` in format ``fmt`` (visp, tum, asl, eth, csv, auto).

    Several files are read in natural order of their names and concatenated. ``auto`` takes
    the format from the first file (:func:`sniff_pose_format`). A file that fails to read in
    the named format but looks like another says so in the error.

    Parameters
    ----------
    pattern : str or Path
        Glob or path of the pose file(s).
    fmt : {"visp", "tum", "asl", "eth", "csv", "auto"}
        Their format.
    csv_spec : dict, optional
        Column/unit spec for ``csv`` (:func:`read_csv_poses`); required for that format.

    Returns
    -------
    poses : DataFrame
        Pose table (module docstring): ``name, t_s, t_ns, x_m, y_m, z_m, qx, qy, qz, qw,
        pos_valid, rot_valid, origin``, T_W_X in metres, scalar-last quaternion;
        the files' rows concatenated in natural file order.

    Raises
    ------
    InputError
        Unknown ``fmt``, no match, an unrecognised format under ``auto``, ``csv`` without a
        spec, or a reader's error (naming the format the file looks like, if another).
    """
    if fmt not in (*POSE_FORMATS, "auto"):
        raise InputError(f"pose format {fmt!r}; expected one of {list(POSE_FORMATS)} or auto")
    paths = expand_pose_glob(pattern)
    if fmt == "auto":
        fmt = sniff_pose_format(paths[0])
        if fmt is None:
            raise InputError(
                f"{paths[0]}: pose format not recognised; expected a ViSP vpPoseVector YAML "
                "(rows, cols, data), a pose stream (TUM lines t tx ty tz qx qy qz qw, an ASL CSV "
                "whose header names the columns, ETH's t, x, y, z, qx, qy, qz, qw) or a CSV with "
                "a header and --csv-spec"
            )
    try:
        if fmt == "visp":
            return read_visp_poses(paths)
        if fmt in STREAM_POSE_FORMATS:
            return pd.concat([read_stream_poses(p, fmt) for p in paths], ignore_index=True)
        if csv_spec is None:
            raise InputError(f"{pattern}: pose format csv needs a spec declaring the columns and units")
        return pd.concat([read_csv_poses(p, csv_spec) for p in paths], ignore_index=True)
    except InputError as exc:
        looks = next((k for k in map(sniff_pose_format, paths) if k not in (None, fmt)), None)
        if looks is None:
            raise
        raise InputError(f"{exc} (the file looks like a {looks} pose list, not {fmt}: "
                         f"give the pose format {looks})") from exc  # fmt: skip
