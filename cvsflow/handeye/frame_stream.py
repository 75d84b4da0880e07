"""Hand-eye from timestamped frames of a target and the carrier's motion-capture pose stream.

Each frame's carrier pose is the stream's at the frame's time plus the clock offset (linear
position, SLERP rotation: :class:`cvsflow.geometry.PoseCurve`); frames outside the stream or in
one of its gaps are named and left out. The offset is estimated from the frames' PnP poses and
the stream (:func:`cvsflow.handeye.stream_fit.estimate_streams`) where the data determine it,
else held at the value given (0: one clock) with the reason; the hand-eye is then
:func:`cvsflow.handeye.stills.calibrate_hand_eye` on the frames (corner reprojection, the
carrier poses' own errors modelled), up to ``max_frames`` of them spread evenly in time.

In eye-to-hand mode (the target on the carrier) the offset is estimated the same way with the
roles turned: the camera's pose in the target frame against the inverse of the carrier's,
``T_B_C = T_Bm_B^-1 T_W_Bm(t + dt)^-1 T_W_C``, the model of the stream fit with
``T_W_Cm := T_W_Bm^-1``.
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.board import board_object_points
from cvsflow.exceptions import CalibrationError, OptimiseError
from cvsflow.geometry import PoseCurve, invert_T, make_T
from cvsflow.handeye.closed_form import MIN_STILLS
from cvsflow.handeye.stills import calibrate_hand_eye, detect_still_corners
from cvsflow.handeye.stream_fit import MIN_FRAMES, StreamsOptions, estimate_streams, seconds_since
from cvsflow.optimise import solve_pnp_frames

log = logging.getLogger(__name__)

#: Frames of a long recording the hand-eye fit takes, spread evenly in time (its outlier
#: screen and jackknife refit once per frame).
MAX_FRAMES = 100


def _offset(t_ns, T_C_B, t_mocap_ns, T_W_X, mode, dt_offset_s):
    """The offset to interpolate the carrier at and what is known of it (held when undetermined)."""
    held = 0.0 if dt_offset_s is None else float(dt_offset_s)
    if dt_offset_s is not None:
        return held, {"observable": False, "reason": f"given ({held:g} s), not estimated"}, None
    if len(t_ns) < MIN_FRAMES:
        why = f"{len(t_ns)} frames with a target pose (need {MIN_FRAMES}); held at {held:g} s (one clock)"
        return held, {"observable": False, "reason": why}, None
    T_curve = invert_T(T_W_X) if mode == "eye_to_hand" else T_W_X
    try:
        res = estimate_streams(t_ns, invert_T(T_C_B), t_mocap_ns, T_curve, StreamsOptions(dt_fallback_s=held))
    except OptimiseError as exc:
        return held, {"observable": False, "reason": f"{exc}; held at {held:g} s"}, None
    obs = dict(res.observability["dt"])
    if not obs["observable"]:
        obs["reason"] = f"{obs['reason']}; held at {held:g} s (one clock)"
        return held, obs, res
    return res.dt_offset_s, obs, res


def calibrate_from_frames(images, t_frames_ns, t_mocap_ns, T_W_X, board, camera, mode="eye_in_hand",
                          dt_offset_s=None, max_frames=MAX_FRAMES, max_gap_s=None,
                          subpix_window_px=11, **hand_eye_options) -> dict:  # fmt: skip
    """Hand-eye calibration from timestamped frames and the carrier's pose stream.

    Parameters
    ----------
    images : sequence of (str, ndarray)
        ``(name, gray)`` per frame, 8-bit grayscale, in time order.
    t_frames_ns : array_like of int64, shape (N,)
        The frames' times, the camera's clock, ns.
    t_mocap_ns : array_like of int64, shape (M,)
        The pose stream's times, its clock, ns.
    T_W_X : ndarray, shape (M, 4, 4)
        The carrier's pose per sample (``T_W_Cm`` eye-in-hand, ``T_W_Bm`` eye-to-hand), m.
    board : dict
        The board block (chessboard, ChArUco or AprilGrid).
    camera : dict
        Intrinsics (``K``, ``dist``, optional ``std``).
    mode : {"eye_in_hand", "eye_to_hand"}
    dt_offset_s : float, optional
        ``t_stream = t_frame + dt_offset_s``, s; None: estimated where the data determine it,
        else 0 (one clock).
    max_frames : int
        Most frames the hand-eye fit takes, spread evenly in time.
    max_gap_s : float, optional
        Longest stream interval interpolated over, s (default 3 median intervals).
    subpix_window_px : int
        cornerSubPix half window, px.
    **hand_eye_options
        Passed to :func:`cvsflow.handeye.stills.calibrate_hand_eye` (``method``,
        ``pose_noise``, ...).

    Returns
    -------
    dict
        :func:`calibrate_hand_eye`'s result (its ``stills`` the frames used, with ``t_ns``),
        plus ``dt_offset_s``, ``dt_offset_std_s`` (s, null when not estimated or not
        observable), ``dt_used_s``, ``observability`` (``dt`` with its reason), ``frames``
        (every frame: ``name``, ``t_ns``, ``used``, ``reason``) and ``frame_counts``.

    Raises
    ------
    OverlapError
        The stream does not overlap the frames (both spans named).
    CalibrationError
        Fewer than 3 frames with the target and a carrier pose; the fit's own errors.
    """
    t_ns = np.asarray(t_frames_ns, np.int64)
    det = detect_still_corners(images, board, subpix_window_px)
    found = np.array([d["uv_px"] is not None for d in det])
    T_C_B = np.full((len(det), 4, 4), np.nan)
    if found.any():
        uv = np.stack([d["uv_px"] for d, f in zip(det, found, strict=True) if f])
        T, ok = solve_pnp_frames(uv, board_object_points(board), np.asarray(camera["K"], float),
                                 np.asarray(camera.get("dist", np.zeros(5)), float).ravel())  # fmt: skip
        T_C_B[np.flatnonzero(found)[ok]] = T[ok]
    posed = np.isfinite(T_C_B).all(axis=(1, 2))
    dt, obs_dt, streams = _offset(t_ns[posed], T_C_B[posed], t_mocap_ns, T_W_X, mode, dt_offset_s)
    curve = PoseCurve(seconds_since(t_mocap_ns, t_ns[0]), T_W_X, max_gap_s=max_gap_s)
    R, p, _, _, status = curve.at(seconds_since(t_ns, t_ns[0]) + dt)
    frames = []
    for k, d in enumerate(det):
        reason = (d["reason"] if not found[k] else "PnP failed" if not posed[k] else
                  "outside the pose stream" if status[k] == 1 else "in a gap of the pose stream"
                  if status[k] == 2 else "ok")  # fmt: skip
        frames.append({"name": d["name"], "t_ns": int(t_ns[k]), "used": False, "reason": reason})
    usable = np.flatnonzero(posed & (status == 0))
    if len(usable) < MIN_STILLS:
        counts = {r: sum(f["reason"] == r for f in frames) for r in {f["reason"] for f in frames}}
        raise CalibrationError(f"hand-eye from frames: {len(usable)} of {len(det)} frames show the "
                               f"target and have a carrier pose at dt = {dt:.4f} s (need {MIN_STILLS}): "
                               f"{counts}")  # fmt: skip
    spread = np.linspace(0, len(usable) - 1, min(max_frames, len(usable))).round().astype(int)
    pick = usable[np.unique(spread)]
    for k in np.setdiff1d(usable, pick):
        frames[k]["reason"] = f"not picked (at most {max_frames} frames, spread in time)"
    res = calibrate_hand_eye([images[k] for k in pick], make_T(R[pick], p[pick]), board, camera, mode=mode,
                             subpix_window_px=subpix_window_px, detections=[det[k] for k in pick],
                             **hand_eye_options)  # fmt: skip
    for rec, k in zip(res["stills"], pick, strict=True):
        rec["t_ns"] = int(t_ns[k])
        frames[k].update(used=rec["used"], reason=rec["reason"])
    have = obs_dt["observable"]
    res.update(dt_offset_s=dt if have else None, dt_offset_std_s=streams.dt_offset_std_s if have else None,
               dt_used_s=float(dt), observability={"dt": obs_dt}, frames=frames)  # fmt: skip
    res["frame_counts"] = {"n_frames": len(det), "n_target_found": int(found.sum()),
                           "n_posed": int(posed.sum()),
                           "n_outside_stream": int(((status == 1) & posed).sum()),
                           "n_in_stream_gap": int(((status == 2) & posed).sum()), "n_picked": len(pick),
                           "n_used": int(res["n_used"])}  # fmt: skip
    out_of = res["frame_counts"]["n_outside_stream"] + res["frame_counts"]["n_in_stream_gap"]
    if out_of:
        log.warning("hand-eye from frames: %d frames left out: outside the pose stream or in its gaps at "
                    "dt = %.4f s", out_of, dt)  # fmt: skip
    if not have:
        log.warning("hand-eye from frames: dt not observable: %s", obs_dt["reason"])
    return res
