"""A rendered flight as a camera records it: the body's board in images, through a codec.

:func:`cvsflow.synth.flight_demo.render_flight` measures its reference from corners drawn with
independent noise. Here the same flight (true trajectory, on-board log and clock) is rendered
as video frames by a session's camera, lens, image effects and codec (the session renderer,
:mod:`cvsflow.synth.frames`), so the reference is measured as a user's is: corners detected in
coded images, PnP, and the error model's statement of them. Which session's camera films it is
the caller's choice: the validation session's, to test that its fitted error model serves the
flight.
"""

from __future__ import annotations

import logging

import numpy as np

from cvsflow.exceptions import ConfigError
from cvsflow.flight import traj_from_T
from cvsflow.geometry import invert_T
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.flightlog import write_tum
from cvsflow.io.synth_out import PyAvVideoSink, VideoSink, staged_session_dir
from cvsflow.synth.effects import PTS_RATE_HZ
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.frames import FrameEffects, Lighting
from cvsflow.synth.motion import PoseTrack, random_sine_sum
from cvsflow.synth.render import _session_setup, realistic_truth
from cvsflow.synth.session import exposure_times, video_truth
from cvsflow.synth.spec import FPS, parse_session_config

log = logging.getLogger(__name__)

#: The files :func:`render_flight_video` writes.
FLIGHT_VIDEO_FILES = ("video.mp4", "onboard.tum", "truth.parquet", "truth.yaml")


def render_flight_video(session_cfg: dict, out_dir, seed: int = 1, duration_s: float = 60.0,
                        range_m=None) -> dict:
    """Render a flight filmed by a session's camera into ``out_dir``.

    Parameters
    ----------
    session_cfg : dict
        A session's config (``synth``, ``board``): its camera, lens, image effects, codec and
        board (the board the body carries). A hand occluding the board is switched off (nothing
        holds a flying board).
    out_dir : str or Path
        Folder for :data:`FLIGHT_VIDEO_FILES`, written whole or not at all; an existing one
        may hold only those (a previous render's), which are replaced.
    seed : int
        The flight's seed (:func:`cvsflow.synth.flight_demo.render_flight`: trajectory, on-board
        error and clock).
    duration_s : float
        Flight (and video) length, s.
    range_m : (float, float), optional
        Nearest and farthest distance of the body from the camera; default the session's
        ``synth.distance_m``, else (1.0, 4.0).

    Returns
    -------
    summary : dict
        ``n_frames``, ``in_view_fraction``, ``median_blur_px``, ``range_m``, ``codec``.

    Raises
    ------
    ConfigError
        A range outside (0, inf); ``out_dir`` holds files this renderer did not write; the
        session config's own errors.

    Notes
    -----
    truth.parquet holds the true T_L_Q at each written video frame (``frame`` as the decoder
    numbers them, ``t_s`` the true capture time on the reference clock: under a rolling
    shutter the time of the mean row of the board's corners in the image); truth.yaml holds
    ``T_L_C``, ``T_Q_B``, the log ``clock`` and ``board``. The video's container times carry
    the session's timestamp jitter and drops, as the corners stage reads them.
    """
    cfg = {**session_cfg, "synth": {**session_cfg.get("synth", {}), "duration_s": float(duration_s)}}
    occ = dict(cfg["synth"].get("occlusion") or {})
    if occ.get("enabled"):
        cfg["synth"]["occlusion"] = {**occ, "enabled": False}
    spec = parse_session_config(cfg)
    e = spec.effects
    if range_m is None:
        range_m = e.distance_m if e.distance_m is not None else (1.0, 4.0)
    range_m = (float(range_m[0]), float(range_m[1]))
    if not 0.0 < range_m[0] < range_m[1]:
        raise ConfigError(f"render_flight_video: range_m={range_m}; expected 0 < near < far (m)")
    fps = e.fps if spec.realistic else FPS
    demo = render_flight(seed=seed, duration_s=duration_s, fps=fps, range_m=range_m,
                         reference="model")  # fmt: skip
    T_C_L = invert_T(demo.T_L_C)
    track = PoseTrack(lambda t: T_C_L @ demo.body_track(t) @ demo.T_Q_B)
    rngs, _, renderer, _ = _session_setup(spec)
    with staged_session_dir(out_dir, allowed=FLIGHT_VIDEO_FILES) as tmp:
        truth = _write_flight(spec, rngs, renderer, track, demo, tmp, duration_s, session_cfg, seed,
                              range_m)  # fmt: skip
    summary = {"n_frames": len(truth.t_s), "in_view_fraction": float(np.mean(truth.in_view)),
               "median_blur_px": float(np.median(truth.blur_px)), "range_m": list(range_m),
               "codec": e.codec if spec.realistic else "mp4v (legacy writer)"}
    log.info("rendered flight seed %d: %d frames, %.0f %% in view, blur %.1f px, %s", seed,
             summary["n_frames"], 100 * summary["in_view_fraction"], summary["median_blur_px"],
             summary["codec"])
    return summary


def _write_flight(spec, rngs, renderer, track, demo, out_dir, duration_s, session_cfg, seed,
                  range_m):
    """Render the video and write the flight's files into ``out_dir``; the video's truth."""
    e = spec.effects
    if spec.realistic:
        truth, timeline, lighting, _ = realistic_truth(spec, rngs, track)
        with PyAvVideoSink(out_dir / "video.mp4", e.codec, e.image_size, e.fps, crf=e.crf,
                           quality=e.quality, pts_rate_hz=PTS_RATE_HZ) as sink:  # fmt: skip
            for k in range(len(truth.t_s)):
                fx = FrameEffects(hand=None, gain=float(truth.gain[k]),
                                  analog_gain=float(truth.analog_gain[k]), wb_gains=truth.wb_gains[k])
                image = renderer.realistic_frame(track, truth.t_s[k], truth.exposure_s[k],
                                                 truth.blur_px[k], lighting, rngs["images"], fx)
                sink.write(image, timeline.pts[k])
    else:
        n = int(round(duration_s * FPS))
        truth = video_truth(spec, track, exposure_times(rngs["lighting"], np.arange(n) / FPS))
        lighting = Lighting(random_sine_sum(rngs["lighting"], 4, 3, 0.01, 0.1, std=[1.0] * 4))
        with VideoSink(out_dir / "video.mp4", FPS, spec.image_size, spec.video_quality) as sink:
            for k in range(n):
                sink.write(renderer.video_frame(track, truth.t_s[k], truth.exposure_s[k],
                                                truth.blur_px[k], lighting, rngs["images"]))
    t_s = np.asarray(truth.t_s, float)
    if spec.realistic and e.line_delay_s > 0.0:
        # a rolling shutter exposes the board's rows one after another: its pose is seen at the
        # time of the rows it covers (as the flight stage times the reference)
        seen = truth.in_image & np.isfinite(truth.corners_px[..., 1])
        n_seen = seen.sum(axis=1)
        row_sum = np.where(seen, truth.corners_px[..., 1], 0.0).sum(axis=1)
        mean_row = np.divide(row_sum, n_seen, out=np.zeros(len(t_s)), where=n_seen > 0)
        t_s = t_s + e.line_delay_s * mean_row
    true_table = traj_from_T(t_s, demo.body_track(t_s), attrs={"frames": "T_L_Q (true)"})
    true_table.insert(0, "frame", np.arange(len(t_s)))
    write_parquet(true_table, out_dir / "truth.parquet")
    write_tum(demo.onboard, out_dir / "onboard.tum")
    write_yaml({"T_L_C": demo.T_L_C.tolist(), "T_Q_B": demo.T_Q_B.tolist(),
                "clock": {"dt_offset_s": float(demo.clock.dt_offset_s), "skew": float(demo.clock.skew)},
                "board": dict(session_cfg["board"]), "seed": int(seed), "range_m": list(range_m),
                "duration_s": float(duration_s)}, out_dir / "truth.yaml")  # fmt: skip
    return truth
