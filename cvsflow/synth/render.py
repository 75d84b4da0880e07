"""Render a session: stills, video, Vicon export and ground truth (``data/{session}/``).

The maths lives in ``motion`` (board trajectories), ``camera`` (lens, texture, images),
``markers`` (Vicon markers) and ``session`` (the session as data); this module only runs
them in order and hands the results to ``cvsflow.io.synth_out``.
"""

from __future__ import annotations

import logging
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from cvsflow.exceptions import ConfigError
from cvsflow.geometry import invert_T, pose6_from_T, transform_points
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.mocap.vicon import write_nexus_csv
from cvsflow.io.synth_out import (
    RIG_CAMERA_FILES,
    PyAvVideoSink,
    VideoSink,
    staged_session_dir,
    write_session_tables,
    write_still,
)
from cvsflow.synth.effects import (
    PTS_RATE_HZ,
    auto_exposure,
    make_hand_plan,
    make_hand_texture,
    make_timeline,
    occluded_corners,
    white_balance,
)
from cvsflow.synth.frames import FrameEffects, Lighting, Renderer
from cvsflow.synth.motion import make_hand_motion, random_sine_sum, still_poses
from cvsflow.synth.rig_session import (
    camera_frame_times,
    make_rig_truth,
    rig_truth_document,
    rig_vicon_recording,
    shared_views,
)
from cvsflow.synth.session import (
    camera_track,
    exposure_times,
    make_rig,
    still_outline_B,
    truth_document,
    truth_tables,
    vicon_recording,
    video_truth,
)
from cvsflow.synth.spec import FPS, VICON_RATE_HZ, parse_session_config, random_streams

__all__ = ["render_rig_camera", "render_rig_mocap", "render_session", "render_stills"]

log = logging.getLogger(__name__)


def _session_setup(spec):
    """Random streams, rig, renderer and calibration-still poses of a session.

    Raises
    ------
    ConfigError
        Fewer than ``spec.n_stills`` still poses with the board wholly in view were found.
    """
    rngs = random_streams(spec.seed)
    rig = make_rig(spec, rngs["mounting"])
    markers_B = transform_points(invert_T(rig.T_Bm_B), rig.markers_Bm_m)
    renderer = Renderer(spec, rngs["background"], markers_B)
    T_C_B_stills = still_poses(
        rngs["stills"],
        spec.n_stills,
        spec.K,
        spec.dist,
        spec.image_size,
        still_outline_B(spec.board),
        board=spec.board,
    )
    if len(T_C_B_stills) < spec.n_stills:
        raise ConfigError(
            f"session config, synth.n_stills: found only {len(T_C_B_stills)} still poses with "
            f"the board wholly in view, expected {spec.n_stills} (board too large for the camera?)"
        )
    return rngs, rig, renderer, T_C_B_stills


def _still_images(renderer, T_C_B_stills, rng_images):
    """(file name, uint8 image, T_C_B) of each calibration still, in order."""
    for i, T_C_B in enumerate(T_C_B_stills):
        yield f"still_{i:02d}.png", renderer.still(T_C_B, rng_images), T_C_B


def render_stills(session_cfg: dict) -> list:
    """The session's calibration stills alone, in memory, as ``render_session`` writes them.

    The images stream renders the stills before any video frame, so these are the very
    pixels of ``calib/still_*.png``; no video, Vicon export or truth tables are made.

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][name]`` with its ``synth``, ``board`` and ``markers`` blocks.

    Returns
    -------
    stills : list of (str, ndarray, ndarray)
        ``(file name, 480 x 640 uint8 image, true T_C_B (4, 4), metres)`` per still.

    Raises
    ------
    ConfigError
        As ``render_session``.
    """
    spec = parse_session_config(session_cfg)
    rngs, _, renderer, T_C_B_stills = _session_setup(spec)
    return list(_still_images(renderer, T_C_B_stills, rngs["images"]))


def session_frame_count(session_cfg: dict) -> int:
    """The video frames :func:`render_session` renders for a session (a realistic render's
    dropped capture frames included: an upper bound there).

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][name]``.

    Returns
    -------
    int
    """
    spec = parse_session_config(session_cfg)
    return int(round(spec.duration_s * (spec.effects.fps if spec.realistic else FPS)))


def render_session(session_cfg: dict, out_dir, progress=None) -> dict:
    """Render a synthetic session with known ground truth into ``out_dir``.

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][name]`` with its ``synth``, ``board`` and ``markers`` blocks.
    out_dir : str or Path
        Session folder (``data/{session}``); replaced as a whole only on success.
    progress : callable, optional
        ``progress(n)`` after each video frame rendered (e.g. a
        :class:`cvsflow.io.progress.Progress` of ``session_frame_count`` frames).

    Returns
    -------
    summary : dict
        Counts and timings for the log: frames, in-view share, stills, dropouts, seconds.

    Raises
    ------
    ConfigError
        Missing or out-of-range config values; ``out_dir`` holds foreign files; no still
        pose with the board wholly in view could be found.
    """
    wall_start = time.perf_counter()
    spec = parse_session_config(session_cfg)
    rngs, rig, renderer, T_C_B_stills = _session_setup(spec)
    motion = make_hand_motion(
        rngs["motion"], spec.K, spec.image_size, spec.board.center_B(), spec.effects.distance_m,
        R_face_B=spec.board.R_face_B() if spec.board.kind == "aprilgrid" else None,
    )
    if spec.realistic:
        return _render_realistic(spec, rngs, rig, renderer, T_C_B_stills, motion, out_dir, wall_start,
                                 progress)
    n_frames = int(round(spec.duration_s * FPS))
    exposure_s = exposure_times(rngs["lighting"], np.arange(n_frames) / FPS)
    lighting = Lighting(random_sine_sum(rngs["lighting"], 4, 3, 0.01, 0.1, std=[1.0] * 4))
    truth = video_truth(spec, motion, exposure_s)
    vicon_df, _, n_dropouts = vicon_recording(spec, rig, motion, rngs["vicon"])
    frames_df, corners_df = truth_tables(spec, truth, _camera_truth(spec, rig, motion, truth.t_s))

    out_dir = Path(out_dir)
    stills_truth = {}
    with staged_session_dir(out_dir) as tmp:
        for name, image, T_C_B in _still_images(renderer, T_C_B_stills, rngs["images"]):
            write_still(tmp, name, image)
            stills_truth[name] = {"T_C_B": T_C_B, "pose6": pose6_from_T(T_C_B)}
        render_start = time.perf_counter()
        with VideoSink(tmp / "video.mp4", FPS, spec.image_size, spec.video_quality) as sink:
            for k in range(n_frames):
                sink.write(
                    renderer.video_frame(
                        motion,
                        truth.t_s[k],
                        truth.exposure_s[k],
                        truth.blur_px[k],
                        lighting,
                        rngs["images"],
                    )
                )
                if progress:
                    progress(k + 1)
        render_s = time.perf_counter() - render_start
        write_session_tables(
            tmp,
            vicon_df,
            VICON_RATE_HZ,
            truth_document(spec, rig, n_frames, stills_truth),
            frames_df,
            corners_df,
        )
    summary = {
        "out_dir": str(out_dir),
        "n_stills": len(T_C_B_stills),
        "n_frames": n_frames,
        "in_view_fraction": float(np.mean(truth.in_view)),
        "median_blur_px": float(np.median(truth.blur_px)),
        "n_vicon_samples": len(vicon_df),
        "n_dropouts": n_dropouts,
        "dt_offset_s": rig.dt_offset_s,
        "video_render_s": render_s,
        "video_fps_rendered": n_frames / max(render_s, 1e-9),
        "total_s": time.perf_counter() - wall_start,
    }
    log.info(
        "rendered %d stills, %d frames (%.0f%% in view) at %.1f frames/s, %d Vicon samples, "
        "%d dropouts into %s",
        summary["n_stills"],
        n_frames,
        100 * summary["in_view_fraction"],
        summary["video_fps_rendered"],
        summary["n_vicon_samples"],
        n_dropouts,
        out_dir,
    )
    return summary


def _camera_truth(spec, rig, motion, t_s):
    """T_W_C (N, 4, 4) of the video frames for a moving camera, else None (no truth columns)."""
    if not spec.camera_motion.moving:
        return None
    return camera_track(spec, rig, motion, t_s) @ rig.T_Cm_C


def realistic_truth(spec, rngs, motion):
    """Timeline, exposure, colour, hand and the true per-frame quantities of a realistic render.

    Parameters
    ----------
    spec : SynthSpec
        The checked session (its ``effects`` pick what is simulated).
    rngs : dict of str to numpy.random.Generator
        :func:`cvsflow.synth.spec.random_streams`; uses ``timestamps``, ``exposure``,
        ``lighting``, ``colour`` and ``hand``.
    motion : HandMotion
        The board's motion in C.

    Returns
    -------
    truth : VideoTruth
        With the realistic fields (capture index, line times, occlusion, gains) filled.
    timeline : cvsflow.synth.effects.Timeline
    lighting : Lighting
    hand_textures : dict
        Grip index -> hand texture.
    """
    e = spec.effects
    n_capture = int(round(spec.duration_s * e.fps))
    timeline = make_timeline(n_capture, e.fps, e.jitter_s, e.drop_rate, rngs["timestamps"])
    t_s = timeline.t_s
    n = len(t_s)
    if e.auto_exposure:
        light, exposure_s, analog = auto_exposure(rngs["exposure"], t_s, e)
        e_ref = np.sqrt(e.exposure_range_s[0] * e.exposure_range_s[1])
        gain = light * exposure_s * analog / e_ref
    else:
        exposure_s = exposure_times(rngs["lighting"], t_s)
        light, analog, gain = np.ones(n), np.ones(n), np.ones(n)
    lighting = Lighting(random_sine_sum(rngs["lighting"], 4, 3, 0.01, 0.1, std=[1.0] * 4))
    wb = white_balance(rngs["colour"], t_s, e) if e.colour else np.ones((n, 3))
    truth = video_truth(spec, motion, exposure_s, t_s=t_s)
    corners_B = spec.board.corners_B()
    v = np.nan_to_num(truth.corners_px[..., 1], nan=0.0)
    t_line_s = t_s[:, None] + np.clip(v, 0, None) * e.line_delay_s
    width, height = e.image_size
    uv = truth.corners_px
    with np.errstate(invalid="ignore"):
        in_image = (
            np.isfinite(uv[..., 0]) & (uv[..., 0] >= 0) & (uv[..., 0] <= width - 1)
            & (uv[..., 1] >= 0) & (uv[..., 1] <= height - 1)
        )
    grip = np.full(n, -1)
    occluded = np.zeros(in_image.shape, bool)
    hand_textures = {}
    if e.occlusion:
        plan = make_hand_plan(rngs["hand"], spec.duration_s, spec.board, e)
        grip = np.array([plan.grip_at(t) for t in t_s])
        radius = 0.2 * spec.board.square_m  # a finger this close spoils the corner
        hidden = {}
        for g in np.unique(grip[grip >= 0]):
            hand_textures[int(g)] = make_hand_texture(plan.grips[g], spec.board)
            hidden[int(g)] = occluded_corners(hand_textures[int(g)], corners_B, radius)
        for k in range(n):
            if grip[k] >= 0:
                occluded[k] = hidden[int(grip[k])]
    truth = replace(
        truth, capture_index=timeline.capture_index, t_line_s=t_line_s, in_image=in_image,
        occluded=occluded, grip=grip, gain=gain, analog_gain=analog, light=light, wb_gains=wb,
    )
    return truth, timeline, lighting, hand_textures


def _render_realistic(spec, rngs, rig, renderer, T_C_B_stills, motion, out_dir, wall_start, progress):
    """``render_session`` with the realistic effects (see cvsflow.synth.effects)."""
    e = spec.effects
    truth, timeline, lighting, hand_textures = realistic_truth(spec, rngs, motion)
    vicon_df, _, n_dropouts = vicon_recording(spec, rig, motion, rngs["vicon"])
    frames_df, corners_df = truth_tables(spec, truth, _camera_truth(spec, rig, motion, truth.t_s))
    n_frames = len(truth.t_s)
    out_dir = Path(out_dir)
    stills_truth = {}
    with staged_session_dir(out_dir) as tmp:
        for name, image, T_C_B in _still_images(renderer, T_C_B_stills, rngs["images"]):
            write_still(tmp, name, image)
            stills_truth[name] = {"T_C_B": T_C_B, "pose6": pose6_from_T(T_C_B)}
        render_start = time.perf_counter()
        with PyAvVideoSink(
            tmp / "video.mp4", e.codec, e.image_size, e.fps, crf=e.crf, quality=e.quality,
            pts_rate_hz=PTS_RATE_HZ,
        ) as sink:
            for k in range(n_frames):
                g = int(truth.grip[k])
                fx = FrameEffects(
                    hand=hand_textures.get(g), gain=float(truth.gain[k]),
                    analog_gain=float(truth.analog_gain[k]), wb_gains=truth.wb_gains[k],
                )
                image = renderer.realistic_frame(
                    motion, truth.t_s[k], truth.exposure_s[k], truth.blur_px[k], lighting,
                    rngs["images"], fx,
                )
                sink.write(image, timeline.pts[k])
                if progress:
                    progress(k + 1)
        render_s = time.perf_counter() - render_start
        extra = {
            "preset": e.preset,
            "effects": e.magnitudes(),
            "width": int(e.image_size[0]),
            "height": int(e.image_size[1]),
            "line_delay_s": float(e.line_delay_s),
            "time_base_s": 1.0 / PTS_RATE_HZ,
            "n_capture_frames": int(round(spec.duration_s * e.fps)),
            "dropped_capture_indices": [int(i) for i in timeline.dropped],
            "colour": bool(e.colour),
        }
        write_session_tables(
            tmp, vicon_df, VICON_RATE_HZ, truth_document(spec, rig, n_frames, stills_truth, extra),
            frames_df, corners_df,
        )
    summary = {
        "out_dir": str(out_dir),
        "preset": e.preset,
        "n_stills": len(T_C_B_stills),
        "n_frames": n_frames,
        "n_dropped": len(timeline.dropped),
        "in_view_fraction": float(np.mean(truth.in_view)),
        "occluded_frame_fraction": float(np.mean(np.any(truth.occluded & truth.in_image, axis=1))),
        "median_blur_px": float(np.median(truth.blur_px)),
        "n_vicon_samples": len(vicon_df),
        "n_dropouts": n_dropouts,
        "dt_offset_s": rig.dt_offset_s,
        "video_render_s": render_s,
        "video_fps_rendered": n_frames / max(render_s, 1e-9),
        "total_s": time.perf_counter() - wall_start,
    }
    log.info(
        "rendered (%s) %d stills, %d frames (%d dropped, %.0f%% in view) %dx%d at %.2f frames/s into %s",
        e.preset, len(T_C_B_stills), n_frames, len(timeline.dropped), 100 * summary["in_view_fraction"],
        e.image_size[0], e.image_size[1], summary["video_fps_rendered"], out_dir,
    )
    return summary


def render_rig_mocap(session_cfg: dict, mocap_path, truth_path) -> dict:
    """Render a rig session's Vicon export and the truth of every camera (``data/{rig}/``).

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][rig]`` with ``synth``, ``board``, ``markers`` and ``cameras``
        (:mod:`cvsflow.synth.rig_session`).
    mocap_path, truth_path : str or Path
        Where ``vicon.csv`` (Nexus form, mm) and ``truth.yaml`` (:func:`rig_truth_document`)
        go.

    Returns
    -------
    summary : dict
        Cameras, Vicon samples, dropouts and each camera's true ``dt_offset_s``, for the log.

    Raises
    ------
    ConfigError
        As :func:`cvsflow.synth.rig_session.make_rig_truth` and :func:`shared_views`.
    """
    truth = make_rig_truth(session_cfg)
    vicon_df, _, n_dropouts = rig_vicon_recording(truth)
    write_nexus_csv(vicon_df, mocap_path, rate_hz=VICON_RATE_HZ)
    write_yaml(rig_truth_document(truth, shared_views(truth)), truth_path)
    return {"cameras": list(truth.names), "n_vicon_samples": len(vicon_df), "n_dropouts": n_dropouts,
            "dt_offset_s": [float(v) for v in truth.dt_offset_s]}


def render_rig_camera(session_cfg: dict, camera: str, out_dir) -> dict:
    """Render one camera of a rig session into ``out_dir`` (``data/{rig}/{camera}/``).

    The mono renderer's fast path for that camera (:func:`cvsflow.synth.rig_session.camera_session_config`):
    its calibration stills (``calib/``), the rig's shared views as it sees them
    (``shared/shared_000.png`` ..., the same names in every camera), its video at its own frame
    rate and clock, and its mono ``truth.yaml`` (its mounting and offset, plus ``rig``,
    ``camera_index``, ``clock_offset_s`` and the shared views' ``T_C_B``), ``truth_frames`` and
    ``truth_corners``. Camera i's random streams are ``random_streams([seed, i + 1])``.

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][rig]``.
    camera : str
        The camera's ``name``.
    out_dir : str or Path
        Its folder; replaced as a whole only on success.

    Returns
    -------
    summary : dict
        Frames, frame rate, in-view share, stills, shared views, seconds.

    Raises
    ------
    ConfigError
        Unknown camera; as :func:`make_rig_truth`; too few still poses in view.
    """
    wall_start = time.perf_counter()
    truth = make_rig_truth(session_cfg)
    if camera not in truth.names:
        raise ConfigError(f"rig session config: no camera named {camera!r} (cameras {list(truth.names)})")
    i = truth.names.index(camera)
    spec = truth.specs[i]
    rig = truth.camera_rig(i)
    rngs = random_streams([spec.seed, i + 1])
    markers_B = transform_points(invert_T(rig.T_Bm_B), rig.markers_Bm_m)
    renderer = Renderer(spec, rngs["background"], markers_B)
    T_C_B_stills = still_poses(rngs["stills"], spec.n_stills, spec.K, spec.dist, spec.image_size,
                               still_outline_B(spec.board), board=spec.board)
    if len(T_C_B_stills) < spec.n_stills:
        raise ConfigError(
            f"rig session config, cameras[{camera}].synth.n_stills: found only {len(T_C_B_stills)} "
            f"still poses with the board wholly in view, expected {spec.n_stills}"
        )
    T_C_C0 = truth.T_C_C0(i)
    T_C_B_shared = T_C_C0 @ shared_views(truth)
    motion = truth.view(i)
    t_s = camera_frame_times(spec)
    fps = float(spec.effects.fps)
    exposure_s = exposure_times(rngs["lighting"], t_s)
    lighting = Lighting(random_sine_sum(rngs["lighting"], 4, 3, 0.01, 0.1, std=[1.0] * 4))
    video = video_truth(spec, motion, exposure_s, t_s=t_s)
    frames_df, corners_df = truth_tables(spec, video)
    stills_truth = {}
    with staged_session_dir(out_dir, RIG_CAMERA_FILES) as tmp:
        for name, image, T_C_B in _still_images(renderer, T_C_B_stills, rngs["images"]):
            write_still(tmp, name, image)
            stills_truth[name] = {"T_C_B": T_C_B, "pose6": pose6_from_T(T_C_B)}
        shared_truth = {}
        for v, T_C_B in enumerate(T_C_B_shared):
            name = f"shared_{v:03d}.png"
            write_still(tmp, name, renderer.still(T_C_B, rngs["images"]), subdir="shared")
            shared_truth[name] = {"T_C_B": T_C_B, "pose6": pose6_from_T(T_C_B)}
        with VideoSink(tmp / "video.mp4", fps, spec.image_size, spec.video_quality) as sink:
            for k in range(len(t_s)):
                sink.write(renderer.video_frame(motion, t_s[k], video.exposure_s[k], video.blur_px[k],
                                                lighting, rngs["images"]))
        extra = {"rig": {"camera": camera, "camera_index": i, "clock_offset_s": truth.clock_offset_s[i],
                         "T_C0_C": invert_T(T_C_C0)},
                 "shared": shared_truth}  # fmt: skip
        write_yaml(truth_document(spec, rig, len(t_s), stills_truth, extra), tmp / "truth.yaml")
        write_parquet(frames_df, tmp / "truth_frames.parquet")
        write_parquet(corners_df, tmp / "truth_corners.parquet")
    summary = {"camera": camera, "n_frames": len(t_s), "fps": fps, "n_stills": len(T_C_B_stills),
               "n_shared": len(T_C_B_shared), "in_view_fraction": float(np.mean(video.in_view)),
               "dt_offset_s": rig.dt_offset_s, "total_s": time.perf_counter() - wall_start}  # fmt: skip
    log.info("rendered rig camera %s: %d stills, %d shared views, %d frames at %.0f fps (%.0f%% in view)",
             camera, len(T_C_B_stills), len(T_C_B_shared), len(t_s), fps, 100 * summary["in_view_fraction"])
    return summary
