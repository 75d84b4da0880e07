"""Readers of on-board pose logs (PX4 ULog, generic CSV, TUM) and the TUM writer.

Every reader returns the *common trajectory form*: a DataFrame with one row per sample and
columns

=============  ==============================================================================
``t_s``        sample time on the log's own clock, seconds (float64)
``t_ns``       the same time in int64 nanoseconds, exact as the file gives it (last column)
``x_m y_m z_m`` position of the body in the log's world frame, metres (NaN where not valid)
``qx qy qz qw`` orientation of the body in the log's world frame, scalar-last unit quaternion
``pos_valid``  bool: the position of this row may be used
``rot_valid``  bool: the orientation of this row may be used
=============  ==============================================================================

and ``df.attrs`` describing the source (``source``, ``path``, ``frames``, ``t_start_s``,
``t_end_s``, ``span_s`` and reader-specific entries). The pose of a row is ``T_L_Q``: the
quadcopter body frame Q into the estimator's local world frame L (flight frames are described
in :mod:`cvsflow.flight`).

Quaternion order crosses file formats here and in :mod:`cvsflow.io.trajectory`: PX4 logs
``q[0..3]`` scalar-FIRST (w, x, y, z); TUM files and cvsflow are scalar-last (x, y, z, w). TUM,
EuRoC/ASL and KITTI logs are read and written by :mod:`cvsflow.io.trajectory` (exact times).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.exceptions import InputError
from cvsflow.flight import trajectory_frame
from cvsflow.geometry import R_from_euler, quat_from_R
from cvsflow.io import trajectory
from cvsflow.io.mocap.streams import NS_PER, seconds_from_ns, time_to_ns

log = logging.getLogger(__name__)

POSE_COLS = ["x_m", "y_m", "z_m", "qx", "qy", "qz", "qw"]
TRAJ_COLS = ["t_s", *POSE_COLS, "pos_valid", "rot_valid"]

_POS_SCALE = {"m": 1.0, "mm": 1e-3, "cm": 1e-2}
_QUAT_NORM_TOL = 1e-2


def _normalise_quats(q_xyzw, path, what):
    """Unit quaternions (qw >= 0) and a validity mask; NaN rows for zero or non-finite input."""
    q = np.asarray(q_xyzw, dtype=float)
    norm = np.linalg.norm(q, axis=1)
    ok = np.isfinite(norm) & (norm > 1e-9)
    bad_norm = ok & (np.abs(norm - 1.0) > _QUAT_NORM_TOL)
    if bad_norm.any():
        log.warning(
            "%s: %s: %d quaternions have a norm differing from 1 by more than %g; renormalised",
            path,
            what,
            int(bad_norm.sum()),
            _QUAT_NORM_TOL,
        )
    out = np.full_like(q, np.nan)
    out[ok] = q[ok] / norm[ok, None]
    out[ok] = np.where(out[ok, 3:4] < 0, -out[ok], out[ok])
    return out, ok


def _finish(df, attrs):
    """Sort by time, set span attributes and return the common form."""
    df = df.sort_values("t_s", kind="stable").reset_index(drop=True)
    df["pos_valid"] = df["pos_valid"].astype(bool) & np.isfinite(df[["x_m", "y_m", "z_m"]]).all(
        axis=1
    )
    df["rot_valid"] = df["rot_valid"].astype(bool) & np.isfinite(df[["qx", "qy", "qz", "qw"]]).all(
        axis=1
    )
    t = df["t_s"].to_numpy()
    attrs = dict(attrs)
    attrs.update(
        n_samples=int(len(df)),
        t_start_s=float(t[0]) if len(t) else float("nan"),
        t_end_s=float(t[-1]) if len(t) else float("nan"),
        span_s=float(t[-1] - t[0]) if len(t) else 0.0,
        n_pos_invalid=int((~df["pos_valid"]).sum()),
        n_rot_invalid=int((~df["rot_valid"]).sum()),
    )
    df.attrs = attrs
    return df


# --------------------------------------------------------------------------------------------
# TUM, EuRoC/ASL and KITTI (cvsflow.io.trajectory)
# --------------------------------------------------------------------------------------------


def read_trajectory_log(path, fmt: str = "tum", times_path=None) -> pd.DataFrame:
    """Read a TUM, EuRoC/ASL or KITTI trajectory into the common form, times exact.

    Parameters
    ----------
    path : str or Path
        The file (:func:`cvsflow.io.trajectory.read_trajectory`); metres, scalar-last
        quaternion in the common form.
    fmt : {"tum", "asl", "kitti"}
        Its format.
    times_path : str or Path, optional
        KITTI's times file (default beside the poses file, ``<stem>.times.txt``).

    Returns
    -------
    DataFrame
        The common trajectory form (module docstring) with ``t_ns`` exact; quaternions
        sign-normalised (qw >= 0); ``attrs``: the stream table's (``n_duplicates_dropped``:
        rows repeating the time before them, dropped with a warning) and ``source``, the format.

    Raises
    ------
    InputError
        Missing file, a bad line (named), times out of order; the format reader's errors.
    """
    stream = trajectory.read_trajectory(path, fmt, times_path)
    q, ok = _normalise_quats(stream[["qx", "qy", "qz", "qw"]].to_numpy(float), path, "quaternion")
    df = trajectory_frame(stream["t_s"].to_numpy(float), stream[["x_m", "y_m", "z_m"]].to_numpy(float),
                          q, True, ok, t_ns=stream["t_ns"].to_numpy(np.int64))  # fmt: skip
    return _finish(df, {**stream.attrs, "source": fmt, "path": str(path), "frames": "as in the file"})


def read_tum(path) -> pd.DataFrame:
    """Read a TUM trajectory file (``timestamp tx ty tz qx qy qz qw``, ``#`` comments).

    Parameters
    ----------
    path : str or Path
        Text file, whitespace separated; metres, seconds, scalar-last quaternion.

    Returns
    -------
    DataFrame
        :func:`read_trajectory_log` with ``fmt="tum"``: the common form with exact ``t_ns``.

    Raises
    ------
    InputError
        Missing file, a line without 8 numbers (the message names the line), no pose at all.
    """
    return read_trajectory_log(path, "tum")


def write_tum(df: pd.DataFrame, path, only_valid: bool = True) -> None:
    """Write a trajectory in TUM format (``timestamp tx ty tz qx qy qz qw``), atomically.

    Parameters
    ----------
    df : DataFrame
        Common trajectory form (``t_ns`` or ``t_s``, ``x_m..z_m`` metres, ``qx..qw``
        scalar-last).
    path : str or Path
        Output file; readable by evo (``evo_ape tum ref.txt est.txt``).
    only_valid : bool
        Drop rows whose position or orientation is not valid (TUM has no validity flag).

    Returns
    -------
    None
        :func:`cvsflow.io.trajectory.write_tum`: times with 9 decimals from the exact ns,
        values that read back bit-identical.
    """
    trajectory.write_tum(df, path, only_valid)


# --------------------------------------------------------------------------------------------
# Generic CSV
# --------------------------------------------------------------------------------------------

CSV_DEFAULTS = {
    "time_col": "t",
    "time_unit": "s",
    "pos_cols": ["x", "y", "z"],
    "pos_unit": "m",
    "rot": "quat_xyzw",
    "rot_cols": ["qx", "qy", "qz", "qw"],
    "angle_unit": "rad",
    "pos_valid_col": None,
    "rot_valid_col": None,
}


def read_csv_log(path, spec: dict | None = None) -> pd.DataFrame:
    """Read a generic CSV pose log whose columns and units are declared in ``spec``.

    Parameters
    ----------
    path : str or Path
        CSV file with a header row.
    spec : dict
        ``time_col``; ``time_unit`` (s, ms, us, ns); ``pos_cols`` (3 names); ``pos_unit``
        (m, cm, mm); ``rot``: ``quat_xyzw``, ``quat_wxyz`` or ``euler_rpy`` (roll, pitch, yaw
        with R = Rz(yaw) Ry(pitch) Rx(roll)); ``rot_cols`` (4 or 3 names); ``angle_unit``
        (rad, deg; Euler only); optional ``pos_valid_col`` / ``rot_valid_col`` (truthy = valid).
        Missing keys take ``CSV_DEFAULTS``.

    Returns
    -------
    DataFrame
        Common trajectory form in SI units; empty cells give invalid rows (not errors).

    Raises
    ------
    InputError
        Missing file, unknown spec value, a declared column absent from the header, or a cell
        that is not a number (the message names the row and column).
    """
    path = Path(path)
    spec = {**CSV_DEFAULTS, **(spec or {})}
    unknown = set(spec) - set(CSV_DEFAULTS)
    if unknown:
        raise InputError(
            f"{path}: unknown CSV spec keys {sorted(unknown)}; expected {list(CSV_DEFAULTS)}"
        )
    for key, choices in (
        ("time_unit", NS_PER),
        ("pos_unit", _POS_SCALE),
        ("rot", ("quat_xyzw", "quat_wxyz", "euler_rpy")),
        ("angle_unit", ("rad", "deg")),
    ):
        if spec[key] not in choices:
            raise InputError(
                f"{path}: CSV spec {key}={spec[key]!r}; expected one of {list(choices)}"
            )
    n_rot = 3 if spec["rot"] == "euler_rpy" else 4
    if len(spec["pos_cols"]) != 3 or len(spec["rot_cols"]) != n_rot:
        raise InputError(
            f"{path}: CSV spec needs 3 pos_cols and {n_rot} rot_cols for rot={spec['rot']}, got "
            f"{len(spec['pos_cols'])} and {len(spec['rot_cols'])}"
        )
    if not path.is_file():
        raise InputError(f"{path}: file not found (expected a CSV pose log)")
    try:
        # every cell as text: the times are converted exactly (time_to_ns), not through a float
        raw = pd.read_csv(path, skipinitialspace=True, dtype=str)
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not a readable CSV ({exc})") from exc
    raw.columns = [str(c).strip() for c in raw.columns]
    wanted = [spec["time_col"], *spec["pos_cols"], *spec["rot_cols"]]
    wanted += [c for c in (spec["pos_valid_col"], spec["rot_valid_col"]) if c]
    missing = [c for c in wanted if c not in raw.columns]
    if missing:
        raise InputError(f"{path}: header lacks column(s) {missing}; found {list(raw.columns)}")
    num = {}
    for c in wanted:
        v = pd.to_numeric(raw[c], errors="coerce")
        bad = v.isna() & raw[c].notna()
        if bad.any():
            i = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{path}, row {i + 2}, column {c}: {raw[c].iloc[i]!r} is not a number")
        num[c] = v.to_numpy(dtype=float)
    t = num[spec["time_col"]]
    if np.isnan(t).any():
        i = int(np.flatnonzero(np.isnan(t))[0])
        raise InputError(f"{path}, row {i + 2}, column {spec['time_col']}: empty time cell")
    t_ns = np.array([time_to_ns(s.strip(), spec["time_unit"]) for s in raw[spec["time_col"]]], np.int64)
    t_s = seconds_from_ns(t_ns)
    p = np.column_stack([num[c] for c in spec["pos_cols"]]) * _POS_SCALE[spec["pos_unit"]]
    r = np.column_stack([num[c] for c in spec["rot_cols"]])
    if spec["rot"] == "euler_rpy":
        if spec["angle_unit"] == "deg":
            r = np.deg2rad(r)
        ok = np.isfinite(r).all(1)
        q = np.full((len(r), 4), np.nan)
        if ok.any():
            q[ok] = quat_from_R(R_from_euler(r[ok]))
    else:
        if spec["rot"] == "quat_wxyz":
            r = r[:, [1, 2, 3, 0]]
        q, ok = _normalise_quats(r, path, "quaternion")
    pos_valid = np.isfinite(p).all(1)
    if spec["pos_valid_col"]:
        pos_valid &= np.nan_to_num(num[spec["pos_valid_col"]]) != 0
    if spec["rot_valid_col"]:
        ok &= np.nan_to_num(num[spec["rot_valid_col"]]) != 0
    p = np.where(pos_valid[:, None], p, np.nan)
    df = trajectory_frame(t_s, p, q, pos_valid, ok, t_ns=t_ns)
    n_bad = int((~pos_valid).sum())
    if n_bad:
        log.warning("%s: %d of %d rows have no valid position", path, n_bad, len(df))
    return _finish(df, {"source": "csv", "path": str(path), "frames": "as declared", "spec": spec})


# --------------------------------------------------------------------------------------------
# PX4 ULog
# --------------------------------------------------------------------------------------------


def _open_ulog(path):
    """Parse a ULog file with pyulog; unreadable files become InputError."""
    from pyulog import ULog

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found (expected a PX4 .ulg log)")
    try:
        return ULog(str(path))
    except Exception as exc:  # pyulog raises plain exceptions on corrupt files
        raise InputError(f"{path}: not a readable PX4 ULog file ({exc})") from exc


def _topic(ulog, path, name, multi_id=0, required=True):
    """The data of one (topic, multi_id) series, or None when absent and not required."""
    for d in ulog.data_list:
        if d.name == name and d.multi_id == multi_id:
            return d.data
    if required:
        have = sorted({d.name for d in ulog.data_list})
        raise InputError(f"{path}: topic {name}[{multi_id}] not in the log; topics present: {have}")
    return None


def _time_field(data):
    """Sample time of a topic in microseconds: timestamp_sample when logged, else timestamp."""
    key = "timestamp_sample" if "timestamp_sample" in data else "timestamp"
    return np.asarray(data[key], dtype=np.int64), key


def read_ulog_topic(path, topic: str, multi_id: int = 0) -> pd.DataFrame:
    """All fields of one ULog topic series as a DataFrame, plus ``t_s`` (µs since boot / 1e6).

    Parameters
    ----------
    path : str or Path
        PX4 ``.ulg`` file.
    topic : str
        uORB topic name, e.g. ``vehicle_attitude``.
    multi_id : int, default 0
        Instance of a topic logged more than once.

    Returns
    -------
    DataFrame
        ``t_s`` (s since boot, from the topic's timestamp field) then every field as logged
        (PX4 units and frames, no conversion); ``attrs``: ``path``, ``topic``, ``multi_id``,
        ``time_field``.

    Raises
    ------
    InputError
        Unreadable file or topic not logged (the message lists the topics present).
    """
    ulog = _open_ulog(path)
    data = _topic(ulog, Path(path), topic, multi_id)
    df = pd.DataFrame({k: np.asarray(v) for k, v in data.items()})
    us, key = _time_field(data)
    df.insert(0, "t_s", us * 1e-6)
    df.attrs = {"path": str(path), "topic": topic, "multi_id": multi_id, "time_field": key}
    return df


def _interp_valid(t_out, t_in, v_in, valid_in, max_gap_s):
    """Linear interpolation of v_in at t_out; NaN outside, across gaps, next to invalid samples."""
    out = np.full(len(t_out), np.nan)
    if len(t_in) < 2:
        return out
    i = np.searchsorted(t_in, t_out, side="right")
    inside = (i > 0) & (i < len(t_in))
    exact_last = t_out == t_in[-1]
    i = np.clip(i, 1, len(t_in) - 1)
    t0, t1 = t_in[i - 1], t_in[i]
    ok = inside & valid_in[i - 1] & valid_in[i] & ((t1 - t0) <= max_gap_s)
    ok |= exact_last & valid_in[-1]
    w = np.where(t1 > t0, (t_out - t0) / np.where(t1 > t0, t1 - t0, 1.0), 0.0)
    val = (1 - w) * v_in[i - 1] + w * v_in[i]
    val = np.where(exact_last, v_in[-1], val)
    out[ok] = val[ok]
    return out


def read_ulog(path, source: str = "local_position", max_gap_s: float = 0.5) -> pd.DataFrame:
    """Read the on-board pose estimate of a PX4 ULog into the common trajectory form.

    Parameters
    ----------
    path : str or Path
        PX4 ``.ulg`` file.
    source : {"local_position", "odometry"}
        ``local_position``: orientation from ``vehicle_attitude`` (rows at its sample times)
        and position from ``vehicle_local_position`` linearly interpolated to them (only
        between two samples both valid and at most ``max_gap_s`` apart). ``odometry``:
        position and orientation from ``vehicle_odometry``.
    max_gap_s : float
        Longest gap between position samples bridged by interpolation, seconds.

    Returns
    -------
    DataFrame
        Common form, plus ``xy_valid`` and ``z_valid`` columns (``local_position``). Times are
        seconds since boot (PX4 µs / 1e6). Frames: PX4's own, L = local NED (x north, y east,
        z down), Q = body FRD (x forward, y right, z down); both right-handed, so
        ``T_L_Q`` is an ordinary rigid transform. ``q[0..3]`` (w, x, y, z, rotating FRD
        into NED) is reordered to scalar-last. Where the log marks the horizontal position
        invalid (``xy_valid = 0``), x and y are NaN and ``pos_valid`` is False; the same for z
        with ``z_valid``. ``attrs``: ``topics`` (per series: ``n``, ``t_first_us``,
        ``t_last_us``), ``t_start_s``/``t_end_s``/``span_s`` of the returned data (the
        effective span), ``header_duration_s`` (ULog header, which can be far longer),
        ``xy_valid_fraction``, ``z_valid_fraction``, ``warnings`` (list of str).

    Raises
    ------
    InputError
        Unreadable file, missing topic or field (named), unknown ``source``.
    """
    path = Path(path)
    if source not in ("local_position", "odometry"):
        raise InputError(f"{path}: source={source!r}; expected 'local_position' or 'odometry'")
    ulog = _open_ulog(path)
    warnings_ = []
    topics = {}

    def summary(name, data):
        us, key = _time_field(data)
        topics[name] = {
            "n": int(len(us)),
            "t_first_us": int(us[0]) if len(us) else None,
            "t_last_us": int(us[-1]) if len(us) else None,
            "time_field": key,
        }
        return us

    def field(data, name, f):
        if f not in data:
            raise InputError(f"{path}: topic {name}, field {f} missing; fields: {sorted(data)}")
        return np.asarray(data[f], dtype=float)

    if source == "local_position":
        att = _topic(ulog, path, "vehicle_attitude")
        lpos = _topic(ulog, path, "vehicle_local_position")
        us_att = summary("vehicle_attitude", att)
        t_att = us_att * 1e-6
        t_pos = summary("vehicle_local_position", lpos) * 1e-6
        q_wxyz = np.column_stack([field(att, "vehicle_attitude", f"q[{k}]") for k in range(4)])
        q, rot_ok = _normalise_quats(q_wxyz[:, [1, 2, 3, 0]], path, "vehicle_attitude.q")
        xy_valid = field(lpos, "vehicle_local_position", "xy_valid") != 0
        z_valid = field(lpos, "vehicle_local_position", "z_valid") != 0
        order = np.argsort(t_pos, kind="stable")
        t_pos = t_pos[order]
        xyz = [field(lpos, "vehicle_local_position", f)[order] for f in ("x", "y", "z")]
        xy_valid, z_valid = xy_valid[order], z_valid[order]
        x = _interp_valid(t_att, t_pos, xyz[0], xy_valid, max_gap_s)
        y = _interp_valid(t_att, t_pos, xyz[1], xy_valid, max_gap_s)
        z = _interp_valid(t_att, t_pos, xyz[2], z_valid, max_gap_s)
        df = trajectory_frame(
            t_att, np.column_stack([x, y, z]), q,
            np.isfinite(x) & np.isfinite(y) & np.isfinite(z), rot_ok,
            xy_valid=np.isfinite(x) & np.isfinite(y), z_valid=np.isfinite(z), t_ns=us_att * 1000,
        )  # fmt: skip
        xy_frac = float(xy_valid.mean()) if len(xy_valid) else 0.0
        z_frac = float(z_valid.mean()) if len(z_valid) else 0.0
        for name, n_bad in (
            ("xy_valid", int((~xy_valid).sum())),
            ("z_valid", int((~z_valid).sum())),
        ):
            if n_bad:
                axes = "x and y" if name == "xy_valid" else "z"
                msg = (
                    f"{path}: vehicle_local_position {name} = 0 in {n_bad} of "
                    f"{len(xy_valid)} samples; {axes} set to NaN there and pos_valid False"
                )
                log.warning(msg)
                warnings_.append(msg)
        extra = {"xy_valid_fraction": xy_frac, "z_valid_fraction": z_frac}
    else:
        odo = _topic(ulog, path, "vehicle_odometry")
        us = summary("vehicle_odometry", odo)
        t = us * 1e-6
        pf = (
            ("position[0]", "position[1]", "position[2]")
            if "position[0]" in odo
            else ("x", "y", "z")
        )
        p = np.column_stack([field(odo, "vehicle_odometry", f) for f in pf])
        q_wxyz = np.column_stack([field(odo, "vehicle_odometry", f"q[{k}]") for k in range(4)])
        q, rot_ok = _normalise_quats(q_wxyz[:, [1, 2, 3, 0]], path, "vehicle_odometry.q")
        frame_key = "pose_frame" if "pose_frame" in odo else "local_frame"
        if frame_key in odo:
            frames_logged = sorted({int(v) for v in np.asarray(odo[frame_key])})
            topics["vehicle_odometry"][frame_key] = frames_logged
        pos_ok = np.isfinite(p).all(1)
        df = trajectory_frame(t, p, q, pos_ok, rot_ok, t_ns=us * 1000)
        if (~pos_ok).any():
            n_bad = int((~pos_ok).sum())
            msg = f"{path}: vehicle_odometry position NaN in {n_bad} of {len(t)} samples"
            log.warning(msg)
            warnings_.append(msg)
        extra = {}
    header_s = (ulog.last_timestamp - ulog.start_timestamp) * 1e-6
    out = _finish(
        df,
        {
            "source": f"px4_ulog:{source}",
            "path": str(path),
            "frames": "L = local NED, Q = body FRD",
            "topics": topics,
            "header_duration_s": float(header_s),
            "warnings": warnings_,
            **extra,
        },
    )
    if header_s > out.attrs["span_s"] + 1.0:
        msg = (
            f"{path}: ULog header spans {header_s:.3f} s but the pose data span "
            f"{out.attrs['span_s']:.3f} s ({out.attrs['t_start_s']:.6f} to "
            f"{out.attrs['t_end_s']:.6f} s since boot); using the data span"
        )
        log.warning(msg)
        out.attrs["warnings"].append(msg)
    if not out["pos_valid"].any():
        out.attrs["warnings"].append(f"{path}: no valid position sample at all")
    return out


def write_flight_demo(demo, out_dir) -> None:
    """Write a rendered flight (:class:`cvsflow.synth.flight_demo.FlightDemo`) as the files a real
    flight session has, plus its truth: ``reference.parquet`` (T_C_B per video frame with its
    covariance columns S00..S55; from a PnP reference the flip term's ``flip_*``, from a PnP or
    rig reference the calibration's factor ``G{i}_{c}``),
    ``onboard.tum`` (the log), ``truth.parquet`` (true T_L_Q at the frames),
    ``injected.parquet`` and ``truth.yaml`` (T_L_C, T_Q_B, clock).

    Parameters
    ----------
    demo : FlightDemo
        The rendered flight.
    out_dir : str or Path
        The flight's data folder, ``data/flights/{flight}``.

    Returns
    -------
    None
    """
    from cvsflow.flight import factor_columns, flip_columns, sigma_columns
    from cvsflow.io.files import write_parquet, write_yaml

    out_dir = Path(out_dir)
    parts = [demo.reference.reset_index(drop=True), sigma_columns(demo.Sigma_ref)]
    if demo.flip_ref is not None:
        parts.append(flip_columns(demo.flip_ref))
    if demo.cal_factor is not None:
        parts.append(factor_columns(demo.cal_factor))
    ref = pd.concat(parts, axis=1)
    write_parquet(ref, out_dir / "reference.parquet")
    write_tum(demo.onboard, out_dir / "onboard.tum")
    write_parquet(demo.truth, out_dir / "truth.parquet")
    write_parquet(demo.injected, out_dir / "injected.parquet")
    write_yaml({"T_L_C": demo.T_L_C, "T_Q_B": demo.T_Q_B,
                "clock": {"dt_offset_s": demo.clock.dt_offset_s, "skew": demo.clock.skew}},
               out_dir / "truth.yaml")


def read_flight_log(path, fmt, ulog_source="local_position", csv_spec=None, times_path=None) -> pd.DataFrame:
    """An on-board log in the common form, by declared format.

    Parameters
    ----------
    path : str or Path
        The log file.
    fmt : {"ulog", "csv", "tum", "asl", "kitti"}
        Its format (declared in the config, not guessed); ``asl`` is an EuRoC/ASL pose CSV.
    ulog_source : {"local_position", "odometry"}, default "local_position"
        ULog only: see :func:`read_ulog`.
    csv_spec : dict, optional
        CSV only: the column/unit spec of :func:`read_csv_log`.
    times_path : str or Path, optional
        KITTI only: the times file (default ``<stem>.times.txt`` beside the poses).

    Returns
    -------
    DataFrame
        Common trajectory form ``t_s, x_m, y_m, z_m, qx, qy, qz, qw, pos_valid, rot_valid``
        (T_L_Q, s and m), plus the reader's extra columns (``t_ns``, exact) and ``attrs``.

    Raises
    ------
    InputError
        An unknown ``fmt``, or the reader's own errors.
    """
    if fmt == "ulog":
        return read_ulog(path, source=ulog_source)
    if fmt == "csv":
        return read_csv_log(path, csv_spec)
    if fmt in trajectory.FORMATS:
        return read_trajectory_log(path, fmt, times_path)
    raise InputError(f"{path}: unknown flight log format {fmt!r} (expected ulog, csv, "
                     f"{', '.join(trajectory.FORMATS)})")
