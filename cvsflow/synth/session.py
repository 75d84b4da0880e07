"""The demo session as data: configuration, true poses, images and the Vicon recording.

Pure functions of the session config (no file I/O); ``cvsflow.synth.render.render_session`` writes
their results with ``cvsflow.io.synth_out``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
import pandas as pd

from cvsflow.charuco import board_type, charuco_board
from cvsflow.errors import ConfigError
from cvsflow.synth.camera import (
    Board,
    BoardTexture,
    board_roi,
    camera_from_config,
    expose,
    make_background,
    make_board_texture,
    project_points,
    rectangle_outline_B,
    render_board,
    render_board_region,
    undistortion_grid,
    vignetting,
)
from cvsflow.synth.effects import SKIN_BGR, Effects, parse_effects
from cvsflow.synth.markers import add_dropouts, marker_table, true_mounting
from cvsflow.synth.motion import (
    CAMERA_MOTION_TYPES,
    CameraMotion,
    HandMotion,
    board_poses,
    camera_poses,
    random_sine_sum,
)
from cvsflow.transforms import (
    T_from_pose6,
    euler_from_R,
    invert_T,
    quat_from_R,
    transform_points,
)

log = logging.getLogger(__name__)

IMAGE_SIZE = (640, 480)  # width, height, px
FPS = 30.0
VICON_RATE_HZ = 300.0
VICON_TAIL_S = 1.5  # the Vicon keeps recording this long after the video ends
IN_VIEW_MARGIN_PX = 3.0
FOCUS_DEPTH_M = 2.2  # defocus blur grows away from this depth
# Order of the independent random streams; appending keeps earlier streams unchanged.
_STREAMS = (
    "mounting", "stills", "motion", "lighting", "images", "vicon", "background",
    "timestamps", "hand", "exposure", "colour",
)


@dataclass(frozen=True)
class SynthSpec:
    """Everything the renderer needs, read and checked from ``config["sessions"][name]``."""

    seed: int
    duration_s: float
    n_stills: int
    K: np.ndarray
    dist: np.ndarray
    board: Board
    T_Cm_C_design: np.ndarray
    T_Bm_B_design: np.ndarray
    camera_names: tuple
    camera_layout_m: np.ndarray
    board_names: tuple
    board_layout_m: np.ndarray
    marker_placement_sigma_m: float
    marker_noise_sigma_m: float
    dropout_rate_hz: float
    dropout_max_s: float
    vicon_lead_s: float
    image_noise_sigma: float
    video_quality: int
    effects: Effects
    camera_motion: CameraMotion = CameraMotion()

    @property
    def realistic(self) -> bool:
        """True unless the fast preset runs with no effect key: the original demo path."""
        return self.effects.preset != "fast" or bool(self.effects.explicit)

    @property
    def image_size(self):
        """(width, height) of stills and video, px."""
        return self.effects.image_size


def _require(mapping, key, where):
    """``mapping[key]`` or a ConfigError naming the missing key."""
    if not isinstance(mapping, dict) or key not in mapping:
        raise ConfigError(f"session config, {where}: missing key '{key}'")
    return mapping[key]


def parse_session_config(session_cfg) -> SynthSpec:
    """Read and check a session's ``synth``, ``board`` and ``markers`` blocks.

    Parameters
    ----------
    session_cfg : dict
        ``config["sessions"][name]``: ``synth`` (``seed``, ``camera`` with ``fx_px, fy_px,
        cx_px, cy_px`` in px and ``dist`` [k1, k2, p1, p2, k3], ``T_Cm_C_pose6``,
        ``T_Bm_B_pose6`` (m, rad), optional durations in s, noise in m and grey levels, the
        effect keys and ``camera_motion``), ``board`` (``squares_x``, ``squares_y``,
        ``square_m`` in m; ChArUco: ``marker_m``, ``dictionary``) and ``markers`` (per body
        ``camera``/``board``: ``names`` and ``layout_m``, one [x, y, z] in m per name).

    Returns
    -------
    SynthSpec
        The checked specification, with the defaults of absent optional keys filled in.

    Raises
    ------
    ConfigError
        A key is missing or a value is out of its range; the message names the key.
    """
    synth = _require(session_cfg, "synth", "session")
    board_cfg = _require(session_cfg, "board", "session")
    markers_cfg = _require(session_cfg, "markers", "session")
    cam = _require(synth, "camera", "synth")
    K, dist = camera_from_config(
        {k: _require(cam, k, "synth.camera") for k in ("fx_px", "fy_px", "cx_px", "cy_px", "dist")}
    )
    if dist.shape != (5,):
        raise ConfigError(
            f"session config, synth.camera.dist: expected 5 values [k1, k2, p1, p2, k3], "
            f"got {dist.size}"
        )
    layouts = {}
    for body in ("camera", "board"):
        block = _require(markers_cfg, body, "markers")
        names = tuple(_require(block, "names", f"markers.{body}"))
        layout = np.asarray(_require(block, "layout_m", f"markers.{body}"), dtype=float)
        if layout.shape != (len(names), 3) or len(names) < 3:
            raise ConfigError(
                f"session config, markers.{body}.layout_m: expected one [x, y, z] per name "
                f"({len(names)} names, at least 3), got shape {layout.shape}"
            )
        layouts[body] = (names, layout)
    board = Board(
        int(_require(board_cfg, "squares_x", "board")),
        int(_require(board_cfg, "squares_y", "board")),
        float(_require(board_cfg, "square_m", "board")),
    )
    if board_type(board_cfg) == "charuco":
        charuco_board(board_cfg)  # checks marker_m and dictionary (ConfigError)
        board = replace(board, kind="charuco", marker_m=float(board_cfg["marker_m"]),
                        dictionary=str(board_cfg["dictionary"]))
    duration_s = float(synth.get("duration_s", 20.0))
    if not duration_s > 0.0:
        raise ConfigError(f"session config, synth.duration_s: expected > 0 s, got {duration_s}")
    n_stills = int(synth.get("n_stills", 15))
    image_noise_sigma = float(synth.get("image_noise_sigma", 2.0))
    video_quality = int(synth.get("video_quality", 75))
    if n_stills < 1:
        raise ConfigError(f"session config, synth.n_stills: expected >= 1, got {n_stills}")
    return SynthSpec(
        seed=int(_require(synth, "seed", "synth")),
        duration_s=duration_s,
        n_stills=n_stills,
        K=K,
        dist=dist,
        board=board,
        T_Cm_C_design=T_from_pose6(_require(synth, "T_Cm_C_pose6", "synth")),
        T_Bm_B_design=T_from_pose6(_require(synth, "T_Bm_B_pose6", "synth")),
        camera_names=layouts["camera"][0],
        camera_layout_m=layouts["camera"][1],
        board_names=layouts["board"][0],
        board_layout_m=layouts["board"][1],
        marker_placement_sigma_m=float(synth.get("marker_placement_sigma_m", 0.003)),
        marker_noise_sigma_m=float(synth.get("marker_noise_sigma_m", 0.0003)),
        dropout_rate_hz=float(synth.get("dropout_rate_hz", 0.5)),
        dropout_max_s=float(synth.get("dropout_max_s", 0.08)),
        vicon_lead_s=float(synth.get("vicon_lead_s", 2.37)),
        image_noise_sigma=image_noise_sigma,
        video_quality=video_quality,
        effects=parse_effects(synth, image_noise_sigma, video_quality),
        camera_motion=parse_camera_motion(synth.get("camera_motion")),
    )


def parse_camera_motion(cfg) -> CameraMotion:
    """``synth.camera_motion`` (absent: a static camera), checked.

    Parameters
    ----------
    cfg : dict or None
        The ``synth.camera_motion`` block: ``type`` (one of ``CAMERA_MOTION_TYPES``, default
        ``static``) and the :class:`cvsflow.synth.motion.CameraMotion` fields (``radius_m``,
        ``period_s`` > 0; ``amplitude_rad``, ``lift_m`` >= 0). None: a static camera.

    Returns
    -------
    CameraMotion
        The motion, with the defaults of absent keys.

    Raises
    ------
    ConfigError
        Unknown type or key, or a value out of its range; the message names the key.
    """
    if cfg is None:
        return CameraMotion()
    if not isinstance(cfg, dict):
        raise ConfigError(f"session config, synth.camera_motion: expected a mapping, got {cfg!r}")
    known = set(CameraMotion.__dataclass_fields__)
    unknown = sorted(set(cfg) - known)
    if unknown:
        raise ConfigError(
            f"session config, synth.camera_motion: unknown keys {unknown} (expected {sorted(known)})"
        )
    kind = cfg.get("type", "static")
    if kind not in CAMERA_MOTION_TYPES:
        raise ConfigError(
            f"session config, synth.camera_motion.type: {kind!r}; expected one of {CAMERA_MOTION_TYPES}"
        )
    values = {k: float(v) for k, v in cfg.items() if k != "type"}
    for key in ("radius_m", "period_s"):
        if key in values and not values[key] > 0.0:
            raise ConfigError(f"session config, synth.camera_motion.{key}: expected > 0, got {values[key]}")
    for key in ("amplitude_rad", "lift_m"):
        if key in values and not values[key] >= 0.0:
            raise ConfigError(f"session config, synth.camera_motion.{key}: expected >= 0, got {values[key]}")
    return CameraMotion(type=kind, **values)


def random_streams(seed):
    """Independent generators, one per purpose, all derived from ``seed``.

    Parameters
    ----------
    seed : int
        The session's ``synth.seed``.

    Returns
    -------
    rngs : dict of str to numpy.random.Generator
        One generator per name of ``_STREAMS`` (``mounting``, ``stills``, ``motion``, ...),
        spawned from ``SeedSequence(seed)`` in that order, so a stream appended later leaves
        the earlier ones unchanged.
    """
    children = np.random.SeedSequence(seed).spawn(len(_STREAMS))
    return {name: np.random.default_rng(s) for name, s in zip(_STREAMS, children, strict=True)}


@dataclass(frozen=True)
class Rig:
    """The true, fixed geometry of the session (all metres)."""

    T_W_Cm: np.ndarray
    T_Cm_C: np.ndarray
    T_Bm_B: np.ndarray
    markers_Cm_m: np.ndarray  # (4, 3) real marker positions in the true Cm
    markers_Bm_m: np.ndarray  # (4, 3) real marker positions in the true Bm
    dt_offset_s: float  # t_vicon_s = t_video_s + dt_offset_s


def make_rig(spec: SynthSpec, rng) -> Rig:
    """Place the markers (with placement error), define the true bodies, set up the camera.

    The camera sits on a chair, optical axis horizontal, marker body roughly aligned with
    the Vicon axes by hand (a few degrees off). The true time offset is ``vicon_lead_s``
    plus a random fraction of a Vicon sample, so it is never a whole number of samples.

    Parameters
    ----------
    spec : SynthSpec
        The designed mountings, marker layouts (m), placement error sigma (m) and
        ``vicon_lead_s`` (s).
    rng : numpy.random.Generator
        The ``mounting`` stream: marker placement errors, camera position and yaw, the
        sub-sample part of the time offset.

    Returns
    -------
    Rig
        True T_W_Cm, T_Cm_C, T_Bm_B (metres), the real marker positions in Cm and Bm (m) and
        the true ``dt_offset_s`` (t_vicon_s = t_video_s + dt_offset_s, s).
    """
    sigma = spec.marker_placement_sigma_m
    T_Cm_C, markers_Cm = true_mounting(
        spec.T_Cm_C_design, spec.camera_layout_m, rng.normal(0, sigma, spec.camera_layout_m.shape)
    )
    T_Bm_B, markers_Bm = true_mounting(
        spec.T_Bm_B_design, spec.board_layout_m, rng.normal(0, sigma, spec.board_layout_m.shape)
    )
    # Cm is placed so that the optical frame C has its z axis level: the chair stands on
    # the floor and the camera looks horizontally, whatever the designed mounting.
    R_level = _level_camera(T_Cm_C, yaw_rad=np.deg2rad(rng.uniform(-8.0, 8.0)))
    t_W_C = np.array([rng.uniform(-2.2, -1.8), rng.uniform(-0.2, 0.2), rng.uniform(0.75, 0.85)])
    T_W_C = np.eye(4)
    T_W_C[:3, :3] = R_level
    T_W_C[:3, 3] = t_W_C
    T_W_Cm = T_W_C @ invert_T(T_Cm_C)
    sub_sample_s = rng.uniform(0.2, 0.8) / VICON_RATE_HZ
    return Rig(T_W_Cm, T_Cm_C, T_Bm_B, markers_Cm, markers_Bm, spec.vicon_lead_s + sub_sample_s)


def _level_camera(T_Cm_C, yaw_rad):
    """R_W_C of a camera looking horizontally along W's (rotated) x axis, image rows level.

    The small tilt of the marker body this implies is the hand-placement error of the rig.
    """
    # C: x right, y down, z forward; in W (z up): forward = (cos, sin, 0), down = -z_W.
    forward = np.array([np.cos(yaw_rad), np.sin(yaw_rad), 0.0])
    down = np.array([0.0, 0.0, -1.0])
    right = np.cross(down, forward)
    return np.column_stack([right, down, forward])


@dataclass(frozen=True)
class VideoTruth:
    """True per-frame quantities of the video (see docs/contracts.md, truth_frames)."""

    t_s: np.ndarray  # (N,) container time = mid-exposure time, s
    T_C_B: np.ndarray  # (N, 4, 4)
    exposure_s: np.ndarray  # (N,)
    corners_px: np.ndarray  # (N, nx*ny, 2) distorted pixels, NaN where not projectable
    in_view: np.ndarray  # (N,) bool
    blur_px: np.ndarray  # (N,) largest corner travel during the exposure, px
    # Realistic renders only (None on the demo's fast path):
    capture_index: np.ndarray | None = None  # (N,) index in the regular capture sequence
    t_line_s: np.ndarray | None = None  # (N, M) capture time of each corner's image row, s
    in_image: np.ndarray | None = None  # (N, M) bool, corner inside the image
    occluded: np.ndarray | None = None  # (N, M) bool, corner hidden by the hand
    grip: np.ndarray | None = None  # (N,) int, hand grip index (-1: no hand)
    gain: np.ndarray | None = None  # (N,) total sensor gain relative to the reference exposure
    analog_gain: np.ndarray | None = None  # (N,)
    light: np.ndarray | None = None  # (N,) relative scene light
    wb_gains: np.ndarray | None = None  # (N, 3) white-balance gains B, G, R


def exposure_times(rng, t_s):
    """Auto-exposure times (s) at video times ``t_s``: drifting slowly within 8..20 ms.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the drift (a random sum of sines at 0.01..0.08 Hz).
    t_s : ndarray, shape (N,)
        Video frame times, s.

    Returns
    -------
    exposure_s : ndarray, shape (N,)
        Exposure time of each frame, s, in [0.008, 0.020].
    """
    drift = random_sine_sum(rng, 1, 3, 0.01, 0.08, std=[1.0])(t_s)[:, 0]
    return np.clip(0.014 + 0.006 * drift, 0.008, 0.020)


def video_truth(spec: SynthSpec, motion: HandMotion, exposure_s, t_s=None) -> VideoTruth:
    """True board poses, corners, visibility and motion blur of every video frame.

    ``t_s`` (N,) are the frames' container times (default: regular at ``FPS``). Under a
    rolling shutter (``spec.effects.line_delay_s`` > 0) ``corners_px`` are the corners at
    their own row's capture time (``corners_at_line_times``); ``T_C_B`` stays at ``t_s``.

    Parameters
    ----------
    spec : SynthSpec
        Camera (K, dist), board, image size and effects (``line_delay_s``).
    motion : HandMotion
        The board's motion in C (:func:`cvsflow.synth.motion.board_poses`).
    exposure_s : ndarray, shape (N,)
        Exposure time of each frame, s (the blur spans t_s +- exposure_s / 2).
    t_s : ndarray, shape (N,), optional
        Container (mid-exposure) times, s; None: ``duration_s * FPS`` frames at ``FPS``.

    Returns
    -------
    VideoTruth
        ``t_s``, ``T_C_B`` (N, 4, 4, m), ``exposure_s``, ``corners_px`` (N, nx*ny, 2;
        distorted px, NaN where a corner cannot be projected), ``in_view`` (every corner at
        least ``IN_VIEW_MARGIN_PX`` inside the image) and ``blur_px`` (largest corner travel
        over the exposure, px; 0 when none is projectable); the realistic fields None.
    """
    if t_s is None:
        n = int(round(spec.duration_s * FPS))
        t_s = np.arange(n) / FPS
    T_C_B = board_poses(motion, t_s)
    corners_B = spec.board.corners_B()
    corners_px = project_points(T_C_B, corners_B, spec.K, spec.dist)
    if spec.effects.line_delay_s > 0.0:
        corners_px, _ = corners_at_line_times(motion, t_s, corners_B, spec.K, spec.dist,
                                              spec.effects.line_delay_s, corners_px)
    width, height = spec.image_size
    m = IN_VIEW_MARGIN_PX
    with np.errstate(invalid="ignore"):
        inside = (
            (corners_px[..., 0] >= m)
            & (corners_px[..., 0] <= width - 1 - m)
            & (corners_px[..., 1] >= m)
            & (corners_px[..., 1] <= height - 1 - m)
        )
    in_view = np.all(inside, axis=1)
    start = project_points(board_poses(motion, t_s - exposure_s / 2), corners_B, spec.K, spec.dist)
    stop = project_points(board_poses(motion, t_s + exposure_s / 2), corners_B, spec.K, spec.dist)
    travel = np.linalg.norm(stop - start, axis=-1)
    with np.errstate(invalid="ignore"):
        blur_px = np.where(
            np.any(np.isfinite(travel), axis=1), np.nanmax(np.nan_to_num(travel, nan=-1), 1), 0.0
        )
    return VideoTruth(t_s, T_C_B, exposure_s, corners_px, in_view, np.clip(blur_px, 0, None))


def corners_at_line_times(motion, t_s, corners_B, K, dist, line_delay_s, guess_px, n_iter=4):
    """Rolling shutter: corner pixels where each corner is seen at its own row's capture time.

    Row v is captured at t_s + v * line_delay_s; the fixed point v = v(t_s + v * line_delay_s)
    is found by iteration (a contraction: the board moves far less than one row per row time).

    Parameters
    ----------
    motion : HandMotion
        The board's motion in C.
    t_s : array_like, shape (N,)
        Frame times, s: the capture time of image row 0.
    corners_B : ndarray, shape (M, 3)
        Corners in the board frame B, metres.
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        Distortion [k1, k2, p1, p2, k3].
    line_delay_s : float
        Time between the capture of consecutive rows, s.
    guess_px : ndarray, shape (N, M, 2)
        Starting corner pixels (e.g. the global-shutter projection at ``t_s``).
    n_iter : int
        Fixed-point iterations.

    Returns
    -------
    uv_px : ndarray, shape (N, M, 2)
        Distorted corner pixels at their own row's time, px (NaN where not projectable).
    t_line_s : ndarray, shape (N, M)
        Capture time of each corner, s (``t_s + v * line_delay_s`` with v clipped at 0 and a
        NaN v taken as row 0).
    """
    t_s = np.asarray(t_s, float)
    uv = guess_px
    n, m = uv.shape[:2]
    for _ in range(n_iter):
        v = np.nan_to_num(uv[..., 1], nan=0.0)
        t_line = t_s[:, None] + np.clip(v, 0, None) * line_delay_s
        T = board_poses(motion, t_line.ravel()).reshape(n, m, 4, 4)
        p_C = np.einsum("nmij,mj->nmi", T[..., :3, :3], corners_B) + T[..., :3, 3]
        uv = project_points(np.eye(4), p_C.reshape(-1, 3), K, dist).reshape(n, m, 2)
    v = np.nan_to_num(uv[..., 1], nan=0.0)
    return uv, t_s[:, None] + np.clip(v, 0, None) * line_delay_s


@dataclass(frozen=True)
class FrameEffects:
    """Per-frame state of the realistic effects."""

    hand: BoardTexture | None  # hand texture of the current grip, None without a hand
    gain: float  # scene light x exposure x analog gain, relative to the reference
    analog_gain: float
    wb_gains: np.ndarray  # (3,) B, G, R


ILLUMINANT_BGR = np.array([0.92, 1.0, 1.06])  # slightly warm indoor light, per channel


@dataclass(frozen=True)
class Lighting:
    """Slow drifts of the scene lighting (global gain, offset, a soft gradient)."""

    drift: object  # SineSum with 4 channels

    def at(self, t_s):
        """(gain, offset, gradient_x, gradient_y) at one time: grey levels and fractions."""
        d = self.drift(np.array([t_s]))[0]
        return 215.0 * (1.0 + 0.12 * d[0]), 12.0 + 5.0 * d[1], 0.15 * d[2], 0.15 * d[3]


class Renderer:
    """Pre-computed camera, texture and background; renders stills and video frames.

    Parameters
    ----------
    spec : SynthSpec
    rng_background : numpy.random.Generator
        For the static cluttered background of the video and the pale one of the stills.
    markers_B : ndarray, shape (M, 3), optional
        Board markers in B (metres), drawn on the sheet where they lie on it.
    """

    def __init__(self, spec: SynthSpec, rng_background, markers_B=None):
        self.spec = spec
        size = spec.image_size
        self.xy_n = undistortion_grid(spec.K, spec.dist, size)
        self.texture: BoardTexture = make_board_texture(spec.board, markers_B=markers_B)
        self.background = make_background(rng_background, size)
        self.background_still = make_background(rng_background, size, n_rects=8, light=True)
        self.shading = vignetting(size, spec.K)
        width, height = size
        u, v = np.meshgrid(
            np.linspace(-0.5, 0.5, width, dtype=np.float32),
            np.linspace(-0.5, 0.5, height, dtype=np.float32),
        )
        self.ramp_u, self.ramp_v = u, v

    def board_layer(self, T_C_B_sub):
        """Mean of the board layer over sub-frame poses (N, 4, 4): motion blur."""
        layers = [
            render_board(T, self.texture, self.xy_n, self.spec.K, self.spec.dist)
            for T in T_C_B_sub
        ]
        return np.mean(layers, axis=0) if len(layers) > 1 else layers[0]

    def compose(self, layer, background, gain, offset, grad_u, grad_v, depth_m, rng):
        """Composite the board over the background, light it and expose it (uint8)."""
        reflectance = layer[..., 0] + (1.0 - layer[..., 1]) * background
        shading = self.shading * (1.0 + grad_u * self.ramp_u + grad_v * self.ramp_v)
        defocus_px = 0.5 + 1.5 * abs(1.0 / max(depth_m, 0.3) - 1.0 / FOCUS_DEPTH_M)
        return expose(
            reflectance * shading, gain, offset, defocus_px, self.spec.image_noise_sigma, rng
        )

    def still(self, T_C_B, rng):
        """A calibration still (uint8, 480 x 640): pale background, steady light, slight blur."""
        layer = self.board_layer(T_C_B[None])
        return self.compose(
            layer, self.background_still, 220.0, 10.0, 0.05, -0.05, T_C_B[2, 3], rng
        )

    def realistic_frame(self, motion, t_s, exposure_s, blur_px, lighting: Lighting, rng, fx):
        """A video frame with the realistic effects (``fx``: ``FrameEffects``), uint8 (H, W[, 3]).

        Under a rolling shutter the image is rendered in bands of ``band_rows`` rows, each
        with the board (and the hand) at the band's own capture time t_s + row * line_delay_s,
        and motion blur sampled per band over the exposure.
        """
        e = self.spec.effects
        width, height = e.image_size
        n_sub = int(np.clip(np.ceil(blur_px / 1.5) + 1, 1, 10))
        offsets = exposure_s * ((np.arange(n_sub) + 0.5) / n_sub - 0.5)
        if e.line_delay_s > 0.0:
            starts = np.arange(0, height, e.band_rows)
            stops = np.minimum(starts + e.band_rows, height)
            t_band = t_s + 0.5 * (starts + stops - 1) * e.line_delay_s
        else:
            starts, stops, t_band = np.array([0]), np.array([height]), np.array([t_s])
        T_all = board_poses(motion, (t_band[:, None] + offsets[None]).ravel()).reshape(
            len(t_band), n_sub, 4, 4
        )
        layers = [(self.texture, np.zeros((height, width, 2), np.float32))]
        if fx.hand is not None:
            layers.append((fx.hand, np.zeros((height, width, 2), np.float32)))
        K, dist = self.spec.K, self.spec.dist
        for b in range(len(t_band)):
            for j in range(n_sub):
                T = T_all[b, j]
                for texture, acc in layers:
                    roi = board_roi(T, texture, K, dist, (width, height))
                    if roi is None:
                        continue
                    x0, y0, x1, y1 = roi
                    y0, y1 = max(y0, int(starts[b])), min(y1, int(stops[b]))
                    if y1 <= y0:
                        continue
                    acc[y0:y1, x0:x1] += render_board_region(T, texture, self.xy_n, K, (x0, y0, x1, y1))
        board = layers[0][1] / np.float32(n_sub)
        grey = board[..., 0] + (1.0 - board[..., 1]) * self.background
        hand_alpha = layers[1][1][..., 1] / np.float32(n_sub) if fx.hand is not None else None
        gain, offset, grad_u, grad_v = lighting.at(t_s)
        shading = self.shading * (1.0 + grad_u * self.ramp_u + grad_v * self.ramp_v)
        if e.colour:
            refl = np.repeat(grey[..., None], 3, axis=2)
            if hand_alpha is not None:
                a = hand_alpha[..., None]
                refl = a * SKIN_BGR + (1.0 - a) * refl
            radiance = refl * shading[..., None]
            channel_gain = (gain * fx.gain * fx.wb_gains * ILLUMINANT_BGR).astype(np.float32)
        else:
            if hand_alpha is not None:
                hand = layers[1][1][..., 0] / np.float32(n_sub)
                grey = hand + (1.0 - hand_alpha) * grey
            radiance = grey * shading
            channel_gain = gain * fx.gain
        depth_m = float(T_all[len(t_band) // 2, n_sub // 2, 2, 3])
        defocus_px = e.defocus_base_px + e.defocus_px_m * abs(1.0 / max(depth_m, 0.3) - 1.0 / e.focus_m)
        return expose(
            radiance.astype(np.float32), channel_gain, offset, defocus_px, e.read_sigma, rng,
            shot_gain=e.shot_gain, analog_gain=fx.analog_gain,
        )

    def video_frame(self, motion, t_s, exposure_s, blur_px, lighting: Lighting, rng):
        """A video frame at container time ``t_s`` (mid-exposure), uint8 480 x 640.

        The exposure is sampled with about one sub-frame per 1.5 px of corner travel.
        """
        n_sub = int(np.clip(np.ceil(blur_px / 1.5) + 1, 1, 10))
        t_sub = t_s + exposure_s * ((np.arange(n_sub) + 0.5) / n_sub - 0.5)
        T_sub = board_poses(motion, t_sub)
        layer = self.board_layer(T_sub)
        gain, offset, grad_u, grad_v = lighting.at(t_s)
        depth_m = float(T_sub[n_sub // 2, 2, 3])
        return self.compose(layer, self.background, gain, offset, grad_u, grad_v, depth_m, rng)


def camera_track(spec: SynthSpec, rig: Rig, motion: HandMotion, t_s):
    """True camera-marker body poses T_W_Cm (N, 4, 4) at video times ``t_s`` (s), metres.

    ``rig.T_W_Cm`` at every time for a static camera; else ``camera_poses`` (the chair's pose
    as the start, or the orbit's centre) with the true mounting T_Cm_C.

    Parameters
    ----------
    spec : SynthSpec
        Its ``camera_motion``.
    rig : Rig
        True ``T_W_Cm`` (at video time 0) and ``T_Cm_C``, metres.
    motion : HandMotion
        The board's motion (a hand-held camera makes the board's relative motion).
    t_s : array_like, shape (N,)
        Video-clock times, s.

    Returns
    -------
    T_W_Cm : ndarray, shape (N, 4, 4)
        Camera-marker body pose in the Vicon world W per time, metres.
    """
    T_W_C0 = rig.T_W_Cm @ rig.T_Cm_C
    return camera_poses(spec.camera_motion, motion, T_W_C0, t_s) @ invert_T(rig.T_Cm_C)


def vicon_recording(spec: SynthSpec, rig: Rig, motion: HandMotion, rng):
    """The Vicon export of the session: board and camera markers at 300 Hz in W.

    Both bodies get the same marker noise and dropouts; with ``spec.camera_motion`` moving,
    the camera markers follow ``camera_track`` and the board T_W_Cm(t) T_Cm_C T_C_B(t).

    Parameters
    ----------
    spec : SynthSpec
    rig : Rig
    motion : HandMotion
    rng : numpy.random.Generator
        For marker noise and dropouts.

    Returns
    -------
    markers : pandas.DataFrame
        Wide marker table (``cvsflow.io.vicon`` form), metres, NaN in dropouts.
    T_W_Bm : ndarray, shape (N, 4, 4)
        True board-marker body poses at the Vicon samples.
    n_dropouts : int
    """
    n = int(np.ceil((spec.duration_s + VICON_TAIL_S + rig.dt_offset_s) * VICON_RATE_HZ))
    t_vicon_s = np.arange(n) / VICON_RATE_HZ
    T_C_B = board_poses(motion, t_vicon_s - rig.dt_offset_s)
    if spec.camera_motion.moving:
        T_W_Cm = camera_track(spec, rig, motion, t_vicon_s - rig.dt_offset_s)
        T_W_Bm = T_W_Cm @ rig.T_Cm_C @ T_C_B @ invert_T(rig.T_Bm_B)
        camera_W = transform_points(T_W_Cm[:, None], rig.markers_Cm_m[None])
    else:  # the demo's path, unchanged
        T_W_Bm = rig.T_W_Cm @ rig.T_Cm_C @ T_C_B @ invert_T(rig.T_Bm_B)
        camera_W = np.broadcast_to(transform_points(rig.T_W_Cm, rig.markers_Cm_m), (n, 4, 3))
    board_W = transform_points(T_W_Bm[:, None], rig.markers_Bm_m[None])
    xyz = np.concatenate([camera_W, board_W], axis=1)
    xyz = xyz + rng.normal(0.0, spec.marker_noise_sigma_m, xyz.shape)
    xyz, n_dropouts = add_dropouts(
        xyz, rng, spec.dropout_rate_hz, spec.dropout_max_s, VICON_RATE_HZ
    )
    names = list(spec.camera_names) + list(spec.board_names)
    return marker_table(xyz, names, VICON_RATE_HZ), T_W_Bm, n_dropouts


def truth_tables(spec: SynthSpec, truth: VideoTruth, T_W_C=None):
    """``truth_frames`` and ``truth_corners`` tables (docs/contracts.md).

    ``T_W_C`` (N, 4, 4): the true camera in W per frame, given for a moving camera; it adds
    ``cam_x_m, cam_y_m, cam_z_m, cam_qx, cam_qy, cam_qz, cam_qw`` (T_W_C, metres) to
    ``truth_frames``.

    Parameters
    ----------
    spec : SynthSpec
        Its ``effects.line_delay_s`` (realistic renders).
    truth : VideoTruth
        The video's true per-frame quantities (:func:`video_truth`, realistic fields filled
        by :func:`cvsflow.synth.render.realistic_truth`).
    T_W_C : ndarray, shape (N, 4, 4), optional
        True camera pose in W per frame, metres; None (static camera): no ``cam_*`` columns.

    Returns
    -------
    frames : DataFrame
        ``truth_frames``: one row per frame, ``frame, t_s``, true T_C_B as ``x_m, y_m, z_m``
        (m), ``roll_rad, pitch_rad, yaw_rad`` and ``qx .. qw`` (scalar last), ``in_view``,
        ``blur_px``, ``exposure_s``; realistic renders add ``capture_index``,
        ``line_delay_s``, ``n_visible``, ``n_occluded``, ``grip``, ``gain``, ``analog_gain``,
        ``light``, ``wb_b, wb_g, wb_r``.
    corners : DataFrame
        ``truth_corners``: one row per frame and corner, ``frame, corner, u_px, v_px``
        (distorted px, NaN where not projectable); realistic renders add ``occluded``,
        ``in_image``, ``t_line_s`` (s).
    """
    n = len(truth.t_s)
    rpy = euler_from_R(truth.T_C_B[:, :3, :3])
    q = quat_from_R(truth.T_C_B[:, :3, :3])
    frames = pd.DataFrame(
        {
            "frame": np.arange(n),
            "t_s": truth.t_s,
            "x_m": truth.T_C_B[:, 0, 3],
            "y_m": truth.T_C_B[:, 1, 3],
            "z_m": truth.T_C_B[:, 2, 3],
            "roll_rad": rpy[:, 0],
            "pitch_rad": rpy[:, 1],
            "yaw_rad": rpy[:, 2],
            "qx": q[:, 0],
            "qy": q[:, 1],
            "qz": q[:, 2],
            "qw": q[:, 3],
            "in_view": truth.in_view,
            "blur_px": truth.blur_px,
            "exposure_s": truth.exposure_s,
        }
    )
    if T_W_C is not None:
        q_W_C = quat_from_R(T_W_C[:, :3, :3])
        for j, ax in enumerate("xyz"):
            frames[f"cam_{ax}_m"] = T_W_C[:, j, 3]
        for j, ax in enumerate(("qx", "qy", "qz", "qw")):
            frames[f"cam_{ax}"] = q_W_C[:, j]
    n_corners = truth.corners_px.shape[1]
    corners = pd.DataFrame(
        {
            "frame": np.repeat(np.arange(n), n_corners),
            "corner": np.tile(np.arange(n_corners), n),
            "u_px": truth.corners_px[..., 0].ravel(),
            "v_px": truth.corners_px[..., 1].ravel(),
        }
    )
    if truth.capture_index is not None:
        frames["capture_index"] = truth.capture_index.astype(np.int64)
        frames["line_delay_s"] = float(spec.effects.line_delay_s)
        frames["n_visible"] = np.sum(truth.in_image & ~truth.occluded, axis=1).astype(np.int64)
        frames["n_occluded"] = np.sum(truth.in_image & truth.occluded, axis=1).astype(np.int64)
        frames["grip"] = truth.grip.astype(np.int64)
        frames["gain"] = truth.gain
        frames["analog_gain"] = truth.analog_gain
        frames["light"] = truth.light
        for c, name in enumerate("bgr"):
            frames[f"wb_{name}"] = truth.wb_gains[:, c]
        corners["occluded"] = truth.occluded.ravel()
        corners["in_image"] = truth.in_image.ravel()
        corners["t_line_s"] = truth.t_line_s.ravel()
    return frames, corners


def truth_document(spec: SynthSpec, rig: Rig, n_frames, stills, extra=None):
    """The ``truth.yaml`` mapping (docs/contracts.md), plus the designed mountings and stills.

    ``extra`` (realistic renders): more keys, e.g. the effects and the dropped capture indices.

    Parameters
    ----------
    spec : SynthSpec
        The camera, board, marker names, seed and designed mountings.
    rig : Rig
        The true geometry (T_Cm_C, T_Bm_B, T_W_Cm in m; marker positions; ``dt_offset_s``).
    n_frames : int
        Video frames written.
    stills : dict
        Still file name to its truth (``T_C_B``, ``pose6``).
    extra : dict, optional
        Keys added last (they override); None or empty: none.

    Returns
    -------
    doc : dict
        The mapping (numpy arrays not yet converted for YAML); ``camera_motion`` is added
        for a moving camera, whose ``T_W_Cm`` is then the pose at video time 0.
    """
    width, height = spec.image_size
    doc = {
        "camera": {"K": spec.K, "dist": spec.dist, "width": width, "height": height},
        "T_Cm_C": rig.T_Cm_C,
        "T_Bm_B": rig.T_Bm_B,
        "T_W_Cm": rig.T_W_Cm,
        "dt_offset_s": rig.dt_offset_s,
        "fps": float(spec.effects.fps),
        "vicon_rate_hz": VICON_RATE_HZ,
        "markers_Cm_m": dict(zip(spec.camera_names, rig.markers_Cm_m, strict=True)),
        "markers_Bm_m": dict(zip(spec.board_names, rig.markers_Bm_m, strict=True)),
        "board": spec.board.config(),
        "n_frames": int(n_frames),
        "seed": spec.seed,
        "duration_s": spec.duration_s,
        "T_Cm_C_design": spec.T_Cm_C_design,
        "T_Bm_B_design": spec.T_Bm_B_design,
        "stills": stills,
    }
    if spec.camera_motion.moving:  # T_W_Cm above is its pose at video time 0
        doc["camera_motion"] = spec.camera_motion.as_dict()
    if extra:
        doc.update(extra)
    return doc


def still_outline_B(board: Board):
    """Points that must be in view in a calibration still: the printed squares' outline.

    Parameters
    ----------
    board : Board
        The board (its printed squares' extent in B).

    Returns
    -------
    points_B : ndarray, shape (24, 3)
        Points along the printed squares' rectangle in B (z = 0), 6 per edge, metres.
    """
    return rectangle_outline_B(board.printed_B(), n_per_edge=6)
