"""Camera effects of the realistic renderer: presets, timestamps, the hand, exposure, colour.

``synth.preset`` (``fast`` or ``realistic``) only fills defaults; every effect has its own
config key with its magnitude, and an explicit key always wins. With the ``fast`` preset and
no effect key the renderer takes exactly the demo's original code path (byte-identical files).

Pure functions and data (no file I/O).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import cv2
import numpy as np

from cvsflow.exceptions import ConfigError
from cvsflow.synth.board_image import BoardTexture, texture_pyramid
from cvsflow.synth.imaging import Board
from cvsflow.synth.motion import random_sine_sum

log = logging.getLogger(__name__)

PTS_RATE_HZ = 30000  # container time base 1/30000 s (MPEG-4 part 2 allows at most 65535 ticks/s)
CODECS = ("mp4v", "h264", "hevc", "mjpeg")

# Defaults of every effect, per preset. ``fast`` reproduces the original demo renderer.
PRESETS = {
    "fast": {
        "image_size": [640, 480],
        "fps": 30.0,
        "distance_m": None,  # None: the demo's log-depth motion about 2 m (1.0 .. 4.0 m)
        "rolling_shutter": {"line_delay_s": 0.0, "band_rows": 24},
        "occlusion": {"enabled": False, "hand_share": 0.75, "reach_squares": [-0.6, 1.4],
                      "episode_s": [1.5, 4.0]},
        "auto_exposure": {"enabled": False, "exposure_s": [0.008, 0.020], "light_drift": 0.25,
                          "lag_s": 0.4},
        "white_balance_drift": {"enabled": False, "drift": 0.0},
        "defocus": {"focus_m": 2.2, "strength_px_m": 1.5, "base_px": 0.5},
        "noise": {"read_sigma": None, "shot_gain": 0.02},  # None: image_noise_sigma
        "codec": {"name": "mp4v", "quality": None, "crf": 23},  # None: video_quality
        "timestamps": {"jitter_s": 0.0, "drop_rate": 0.0},
    },
    "realistic": {
        "image_size": [1280, 720],
        "fps": 30.0,
        "distance_m": [0.5, 2.5],
        "rolling_shutter": {"line_delay_s": 3.0e-5, "band_rows": 24},
        "occlusion": {"enabled": True, "hand_share": 0.75, "reach_squares": [-0.6, 1.4],
                      "episode_s": [1.5, 4.0]},
        "auto_exposure": {"enabled": True, "exposure_s": [0.004, 0.030], "light_drift": 0.3,
                          "lag_s": 0.4},
        "white_balance_drift": {"enabled": True, "drift": 0.08},
        "defocus": {"focus_m": 1.0, "strength_px_m": 2.0, "base_px": 0.6},
        "noise": {"read_sigma": 2.5, "shot_gain": 0.05},
        "codec": {"name": "h264", "quality": 75, "crf": 23},
        "timestamps": {"jitter_s": 0.002, "drop_rate": 0.02},
    },
}


@dataclass(frozen=True)
class Effects:
    """Resolved effect switches and magnitudes of one session (see ``PRESETS`` for units)."""

    preset: str
    image_size: tuple  # (width, height), px; portrait when height > width
    fps: float  # nominal capture rate, Hz
    distance_m: tuple | None  # (min, max) board distance of the hand motion, m
    line_delay_s: float  # rolling shutter: row r is captured r * line_delay_s after row 0
    band_rows: int  # rows rendered with one board pose under a rolling shutter
    occlusion: bool
    hand_share: float  # share of the time a hand covers part of the board
    reach_squares: tuple  # fingertip depth past the outer corner line, squares (min, max)
    episode_s: tuple  # duration of one grip, s (min, max)
    auto_exposure: bool
    exposure_range_s: tuple  # (min, max) exposure time, s
    light_drift: float  # relative amplitude of the scene-light drift the AE follows
    ae_lag_s: float  # AE reaction lag, s
    colour: bool  # white-balance drift: the video is BGR
    wb_drift: float  # relative amplitude of the per-channel gain drift
    focus_m: float
    defocus_px_m: float  # Gaussian sigma per dioptre of focus error, px m
    defocus_base_px: float
    read_sigma: float  # grey levels
    shot_gain: float  # shot-noise variance per grey level
    codec: str
    quality: int  # 1..100 (mp4v, mjpeg)
    crf: int  # 0..51 (h264, hevc)
    jitter_s: float  # container timestamp jitter (1 sigma), s
    drop_rate: float  # share of capture frames never encoded
    explicit: tuple = field(default=())  # effect keys given in the config

    @property
    def legacy_video(self) -> bool:
        """True when the original constant-rate mp4v writer must be used."""
        return self.codec == "mp4v" and self.jitter_s == 0.0 and self.drop_rate == 0.0

    def magnitudes(self) -> dict:
        """Every effect and its magnitude, for truth.yaml (SI units)."""
        return {
            "preset": self.preset,
            "image_size": [int(v) for v in self.image_size],
            "fps": float(self.fps),
            "distance_m": None if self.distance_m is None else [float(v) for v in self.distance_m],
            "rolling_shutter": {"line_delay_s": float(self.line_delay_s), "band_rows": self.band_rows},
            "occlusion": {"enabled": self.occlusion, "hand_share": float(self.hand_share),
                          "reach_squares": [float(v) for v in self.reach_squares],
                          "episode_s": [float(v) for v in self.episode_s]},
            "auto_exposure": {"enabled": self.auto_exposure,
                              "exposure_s": [float(v) for v in self.exposure_range_s],
                              "light_drift": float(self.light_drift), "lag_s": float(self.ae_lag_s)},
            "white_balance_drift": {"enabled": self.colour, "drift": float(self.wb_drift)},
            "defocus": {"focus_m": float(self.focus_m), "strength_px_m": float(self.defocus_px_m),
                        "base_px": float(self.defocus_base_px)},
            "noise": {"read_sigma": float(self.read_sigma), "shot_gain": float(self.shot_gain)},
            "codec": {"name": self.codec, "quality": int(self.quality), "crf": int(self.crf)},
            "timestamps": {"jitter_s": float(self.jitter_s), "drop_rate": float(self.drop_rate)},
        }


def _merged(preset_value, cfg_value):
    """Preset default overridden key by key by the config (one level of nesting)."""
    if isinstance(preset_value, dict) and isinstance(cfg_value, dict):
        return {**preset_value, **cfg_value}
    return preset_value if cfg_value is None else cfg_value


def _pair(value, key, positive=True):
    v = np.asarray(value, dtype=float)
    if v.shape != (2,) or not v[0] <= v[1] or (positive and v[0] <= 0):
        raise ConfigError(
            f"session config, synth.{key}: expected [min, max] with 0 < min <= max, got {value}"
        )
    return (float(v[0]), float(v[1]))


def parse_effects(synth_cfg, image_noise_sigma, video_quality) -> Effects:
    """Resolve ``synth.preset`` and the effect keys of a session's ``synth`` block.

    Parameters
    ----------
    synth_cfg : dict
        The session's ``synth`` block: ``preset`` (default ``fast``) and any effect keys
        (``image_size`` px, ``fps`` Hz, ``distance_m``, ``rolling_shutter``, ``occlusion``,
        ``auto_exposure``, ``white_balance_drift``, ``defocus``, ``noise``, ``codec``,
        ``timestamps``), merged over the preset's values.
    image_noise_sigma : float
        ``synth.image_noise_sigma`` (grey levels): the read noise when ``noise.read_sigma``
        is None.
    video_quality : int
        ``synth.video_quality``: the codec quality when ``codec.quality`` is None.

    Returns
    -------
    Effects
        The resolved effects; ``explicit`` lists the effect keys the block gave itself.

    Raises
    ------
    ConfigError
        Unknown preset or codec; a value out of range (the message names the key).
    """
    preset = synth_cfg.get("preset", "fast")
    if preset not in PRESETS:
        raise ConfigError(f"session config, synth.preset: expected one of {sorted(PRESETS)}, got {preset!r}")
    base = PRESETS[preset]
    r = {k: _merged(v, synth_cfg.get(k)) for k, v in base.items()}
    size = tuple(int(v) for v in r["image_size"])
    if len(size) != 2 or min(size) < 64:
        raise ConfigError(f"session config, synth.image_size: expected [width, height] >= 64 px, got {size}")
    fps = float(r["fps"])
    if not 1.0 <= fps <= 240.0:
        raise ConfigError(f"session config, synth.fps: expected 1..240 Hz, got {fps}")
    distance = None if r["distance_m"] is None else _pair(r["distance_m"], "distance_m")
    rs, occ, ae = r["rolling_shutter"], r["occlusion"], r["auto_exposure"]
    line_delay = float(rs["line_delay_s"])
    if line_delay < 0 or line_delay * size[1] > 1.0 / fps:
        raise ConfigError(
            f"session config, synth.rolling_shutter.line_delay_s: expected 0 .. 1 / (fps * height) = "
            f"{1.0 / (fps * size[1]):.3g} s (readout within one frame period), got {line_delay}"
            + ("" if "line_delay_s" in (synth_cfg.get("rolling_shutter") or {}) else
               f" (the {preset} preset's default; give synth.rolling_shutter.line_delay_s for "
               f"this frame rate and height)")
        )
    codec = r["codec"]
    if codec["name"] not in CODECS:
        raise ConfigError(
            f"session config, synth.codec.name: expected one of {CODECS}, got {codec['name']!r}"
        )
    ts = r["timestamps"]
    jitter, drop = float(ts["jitter_s"]), float(ts["drop_rate"])
    if jitter < 0 or jitter > 0.2 / fps:
        raise ConfigError(
            f"session config, synth.timestamps.jitter_s: expected 0 .. 0.2 / fps = {0.2 / fps:.3g} s, "
            f"got {jitter}"
        )
    if not 0.0 <= drop <= 0.5:
        raise ConfigError(f"session config, synth.timestamps.drop_rate: expected 0 .. 0.5, got {drop}")
    noise = r["noise"]
    return Effects(
        preset=preset,
        image_size=size,
        fps=fps,
        distance_m=distance,
        line_delay_s=line_delay,
        band_rows=int(rs.get("band_rows", 24)),
        occlusion=bool(occ["enabled"]),
        hand_share=float(occ["hand_share"]),
        reach_squares=_pair(occ["reach_squares"], "occlusion.reach_squares", positive=False),
        episode_s=_pair(occ["episode_s"], "occlusion.episode_s"),
        auto_exposure=bool(ae["enabled"]),
        exposure_range_s=_pair(ae["exposure_s"], "auto_exposure.exposure_s"),
        light_drift=float(ae["light_drift"]),
        ae_lag_s=float(ae["lag_s"]),
        colour=bool(r["white_balance_drift"]["enabled"]),
        wb_drift=float(r["white_balance_drift"]["drift"]),
        focus_m=float(r["defocus"]["focus_m"]),
        defocus_px_m=float(r["defocus"]["strength_px_m"]),
        defocus_base_px=float(r["defocus"]["base_px"]),
        read_sigma=float(image_noise_sigma if noise["read_sigma"] is None else noise["read_sigma"]),
        shot_gain=float(noise["shot_gain"]),
        codec=codec["name"],
        quality=int(video_quality if codec["quality"] is None else codec["quality"]),
        crf=int(codec["crf"]),
        jitter_s=jitter,
        drop_rate=drop,
        explicit=tuple(k for k in base if k in synth_cfg),
    )


# ----------------------------------------------------------------------------- timestamps


@dataclass(frozen=True)
class Timeline:
    """Capture and container times of the encoded frames."""

    capture_index: np.ndarray  # (N,) int, index in the regular capture sequence
    t_s: np.ndarray  # (N,) container presentation time = mid-exposure time of row 0, s
    pts: np.ndarray  # (N,) int, presentation timestamps in 1 / PTS_RATE_HZ units
    dropped: np.ndarray  # (D,) int, capture indices never encoded


def make_timeline(n_capture, fps, jitter_s, drop_rate, rng) -> Timeline:
    """Regular capture at ``fps`` with jittered timestamps and dropped frames.

    Capture k is nominally at k / fps; its container time is that plus Gaussian jitter
    (clipped to +-0.4 period so the order never changes), rounded to the 1/90000 s tick.
    Each capture except the first is dropped with probability ``drop_rate``.

    Parameters
    ----------
    n_capture : int
        Captures of the regular sequence.
    fps : float
        Capture rate, Hz.
    jitter_s : float
        Standard deviation of the timestamp jitter, s (the first capture has none).
    drop_rate : float
        Probability that a capture is dropped, 0..1.
    rng : numpy.random.Generator
        The ``timestamps`` stream; not drawn from when ``jitter_s`` and ``drop_rate`` are 0.

    Returns
    -------
    Timeline
        The kept captures: ``capture_index``, container time ``t_s`` (s), ``pts`` (ticks of
        1 / ``PTS_RATE_HZ`` s), and the ``dropped`` capture indices.
    """
    k = np.arange(n_capture)
    t_nom = k / fps
    if jitter_s == 0.0 and drop_rate == 0.0:
        return Timeline(k, t_nom, np.rint(t_nom * PTS_RATE_HZ).astype(np.int64), np.zeros(0, int))
    jitter = np.clip(rng.normal(0.0, jitter_s, n_capture), -0.4 / fps, 0.4 / fps)
    jitter[0] = 0.0
    pts = np.rint((t_nom + jitter) * PTS_RATE_HZ).astype(np.int64)
    drop = rng.uniform(size=n_capture) < drop_rate
    drop[0] = False
    keep = ~drop
    return Timeline(k[keep], pts[keep] / PTS_RATE_HZ, pts[keep], k[drop])


# ----------------------------------------------------------------------------- the hand

SKIN_BGR = np.array([0.36, 0.46, 0.64], np.float32)  # reflectance of skin per channel
SKIN_GREY = float(SKIN_BGR.mean())


@dataclass(frozen=True)
class Grip:
    """One way the hand holds the board: which edge, where along it, how deep the fingers reach."""

    edge: int  # 0 left (x min), 1 right (x max), 2 top (y min), 3 bottom (y max) of the sheet
    along: float  # position along the edge, 0..1 of the printed squares' extent
    reach_m: float  # fingertip distance past the outermost inner-corner line, m (inwards)
    spread_rad: float  # fan angle of the fingers


@dataclass(frozen=True)
class HandPlan:
    """Grips over time: episode k lasts from ``start_s[k]`` and uses grip ``grip_index[k]`` (-1: none)."""

    start_s: np.ndarray
    grip_index: np.ndarray
    grips: tuple

    def grip_at(self, t_s) -> int:
        k = int(np.searchsorted(self.start_s, t_s, side="right") - 1)
        return int(self.grip_index[max(k, 0)])


def make_hand_plan(rng, duration_s, board: Board, effects: Effects) -> HandPlan:
    """Random grip episodes over the video (about ``hand_share`` of the time with a hand).

    Parameters
    ----------
    rng : numpy.random.Generator
        The ``hand`` stream.
    duration_s : float
        Video length, s; episodes cover -1 s to ``duration_s + 1`` s.
    board : Board
        Its ``square_m`` scales the fingers' reach.
    effects : Effects
        ``hand_share`` (probability of a hand per episode), ``reach_squares`` (range of the
        reach, in squares) and ``episode_s`` (range of the episode lengths, s).

    Returns
    -------
    HandPlan
        Episode start times (s), each episode's grip index (-1: no hand) and the grips.
    """
    starts, index, grips = [], [], []
    t = -1.0
    while t < duration_s + 1.0:
        starts.append(t)
        if rng.uniform() < effects.hand_share:
            grips.append(
                Grip(
                    edge=int(rng.integers(0, 4)),
                    along=float(rng.uniform(0.15, 0.85)),
                    reach_m=float(rng.uniform(*effects.reach_squares) * board.square_m),
                    spread_rad=float(rng.uniform(0.05, 0.25)),
                )
            )
            index.append(len(grips) - 1)
        else:
            index.append(-1)
        t += rng.uniform(*effects.episode_s)
    return HandPlan(np.array(starts), np.array(index), tuple(grips))


def hand_polygons_B(grip: Grip, board: Board, n_arc=12):
    """Palm and finger outlines of a grip in the board plane, list of (M, 2) arrays, metres.

    The palm sits on the sheet edge (half of it beyond the sheet), four fingers reach inwards
    so that their tips lie ``reach_m`` past the outermost inner-corner line.

    Parameters
    ----------
    grip : Grip
        Edge, position along it, reach (m) and finger spread (rad).
    board : Board
        Sheet extent and inner-corner grid in B.
    n_arc : int
        Points per half outline of the palm and per fingertip arc.

    Returns
    -------
    polygons : list of ndarray, shape (M, 2)
        Outlines (open; ``cv2.fillPoly`` closes them) in the board plane (x, y in B),
        metres: the palm, the strip from the sheet edge to it when the palm reaches onto the
        sheet, and four fingers.
    """
    s = board.square_m
    sx0, sx1, sy0, sy1 = board.sheet_B()
    cx_max, cy_max = (board.nx - 1) * s, (board.ny - 1) * s
    # Local frame: origin on the edge, "in" pointing into the board, "side" along the edge.
    if grip.edge == 0:
        origin, inward, side, edge_to_line = np.array([sx0, cy_max * grip.along]), [1, 0], [0, 1], 0 - sx0
    elif grip.edge == 1:
        origin, edge_to_line = np.array([sx1, cy_max * grip.along]), sx1 - cx_max
        inward, side = [-1, 0], [0, 1]
    elif grip.edge == 2:
        origin, inward, side, edge_to_line = np.array([cx_max * grip.along, sy0]), [0, 1], [1, 0], 0 - sy0
    else:
        origin, edge_to_line = np.array([cx_max * grip.along, sy1]), sy1 - cy_max
        inward, side = [0, -1], [1, 0]
    inward, side = np.asarray(inward, float), np.asarray(side, float)
    tip_depth = edge_to_line + grip.reach_m  # from the sheet edge, m
    finger_len = 0.085
    palm_depth = max(tip_depth - finger_len, 0.0)  # palm reaches onto the sheet when needed
    polys = []
    a = np.linspace(0, 2 * np.pi, 2 * n_arc, endpoint=False)
    palm_c = origin + inward * (palm_depth - 0.03)
    palm = palm_c + np.outer(0.045 * np.cos(a), side) + np.outer(0.05 * np.sin(a), inward)
    polys.append(palm)
    # The palm also covers the strip from the sheet edge to its own centre (the hand wraps it).
    if palm_depth > 0.03:
        strip = [origin - 0.045 * side, origin + 0.045 * side, palm_c + 0.045 * side, palm_c - 0.045 * side]
        polys.append(np.array(strip))
    for i, off in enumerate((-1.5, -0.5, 0.5, 1.5)):
        ang = off * grip.spread_rad / 1.5
        d = np.cos(ang) * inward + np.sin(ang) * side
        n = np.array([-d[1], d[0]])
        base = origin + inward * palm_depth + side * (off * 0.019)
        length = finger_len * (0.8 if i in (0, 3) else 1.0)
        width = 0.0085
        half = np.linspace(-np.pi / 2, np.pi / 2, n_arc)
        tip = (
            base + d * (length - width)
            + np.outer(np.sin(half), n * width) + np.outer(np.cos(half), d * width)
        )
        poly = np.vstack([base - n * width, tip[::-1] if False else tip, base + n * width])
        polys.append(poly)
    return polys


def make_hand_texture(grip: Grip, board: Board, ppm=600.0, n_levels=5) -> BoardTexture:
    """Texture pyramid of the hand in the board plane (channel 0 skin reflectance x alpha, 1 alpha).

    Its extent covers the sheet plus a margin for the palm beyond the sheet edge.

    Parameters
    ----------
    grip : Grip
        The hand's grip (:func:`hand_polygons_B`).
    board : Board
        The board whose sheet (plus 0.1 m) the texture covers.
    ppm : float
        Texels per metre of the finest level.
    n_levels : int
        Pyramid levels, each half the resolution of the previous one.

    Returns
    -------
    BoardTexture
        Channel 0 ``SKIN_GREY`` times coverage, channel 1 coverage of the hand (anti-aliased).
    """
    sx0, sx1, sy0, sy1 = board.sheet_B()
    margin = 0.1
    x0, y0 = sx0 - margin, sy0 - margin
    step = 2**n_levels
    cols = int(np.ceil((sx1 - sx0 + 2 * margin) * ppm / step) * step)
    rows = int(np.ceil((sy1 - sy0 + 2 * margin) * ppm / step) * step)
    alpha = np.zeros((rows, cols), np.float32)
    shift = 4
    for poly in hand_polygons_B(grip, board):
        pts = np.rint(((poly - [x0, y0]) * ppm - 0.5) * 16).astype(np.int32)
        cv2.fillPoly(alpha, [pts], 1.0, cv2.LINE_AA, shift)
    level = np.dstack([alpha * np.float32(SKIN_GREY), alpha]).astype(np.float32)
    return texture_pyramid(level, ppm, n_levels, x0, y0)


def occluded_corners(texture: BoardTexture, corners_B, radius_m):
    """Corners (bool (M,)) with hand coverage > 0.5 anywhere within ``radius_m`` in the board plane.

    Parameters
    ----------
    texture : BoardTexture
        The hand texture (:func:`make_hand_texture`); its finest level is used.
    corners_B : ndarray, shape (M, 3) or (M, 2)
        Corners in the board frame B, metres (x, y used).
    radius_m : float
        Distance from a corner within which a covered texel hides it, m (at least one texel).

    Returns
    -------
    occluded : ndarray of bool, shape (M,)
        True where the hand hides the corner; False outside the texture.
    """
    alpha = texture.levels[0][..., 1]
    ppm = texture.ppm[0]
    r = max(int(np.ceil(radius_m * ppm)), 1)
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    grown = cv2.dilate((alpha > 0.5).astype(np.uint8), kernel)
    c = np.floor((corners_B[:, 0] - texture.x0_m) * ppm).astype(int)
    rr = np.floor((corners_B[:, 1] - texture.y0_m) * ppm).astype(int)
    inside = (c >= 0) & (c < alpha.shape[1]) & (rr >= 0) & (rr < alpha.shape[0])
    out = np.zeros(len(corners_B), bool)
    out[inside] = grown[rr[inside], c[inside]] > 0
    return out


# ----------------------------------------------------------------------------- exposure, colour


def auto_exposure(rng, t_s, effects: Effects):
    """Scene light, exposure time and analog gain of an auto-exposure camera at times ``t_s``.

    The scene light drifts by ``light_drift``; the AE aims exposure x gain at the inverse of
    the light it saw ``lag_s`` ago, using exposure first (within ``exposure_s``), gain for the
    rest. So the blur follows the exposure and the brightness shows the AE's lag.

    Parameters
    ----------
    rng : numpy.random.Generator
        The ``exposure`` stream (draws the light's drift).
    t_s : array_like, shape (N,)
        Frame times, s.
    effects : Effects
        ``light_drift`` (relative amplitude), ``ae_lag_s`` (s) and ``exposure_range_s``
        (min, max exposure, s; the reference exposure is their geometric mean).

    Returns
    -------
    light, exposure_s, gain : ndarray, shape (N,)
        Relative scene light, exposure time (s), analog gain (1 at the reference exposure).
    """
    drift = random_sine_sum(rng, 1, 3, 0.02, 0.15, std=[1.0])
    t_s = np.asarray(t_s, float)
    light = 1.0 + effects.light_drift * np.tanh(drift(t_s)[:, 0])
    seen = 1.0 + effects.light_drift * np.tanh(drift(t_s - effects.ae_lag_s)[:, 0])
    e_min, e_max = effects.exposure_range_s
    e_ref = np.sqrt(e_min * e_max)
    want = e_ref / seen  # exposure x gain the AE wants, s
    exposure = np.clip(want, e_min, e_max)
    gain = np.clip(want / exposure, 1.0, 8.0)
    return light, exposure, gain


def white_balance(rng, t_s, effects: Effects):
    """Per-channel (B, G, R) gains at times ``t_s``, shape (N, 3): 1 + drift x slow sines, G fixed.

    Parameters
    ----------
    rng : numpy.random.Generator
        The ``colour`` stream.
    t_s : array_like, shape (N,)
        Frame times, s.
    effects : Effects
        ``wb_drift``: largest relative change of the B and R gains.

    Returns
    -------
    gains : ndarray, shape (N, 3)
        White-balance gains B, G, R per frame (G is 1; B and R within 1 +- ``wb_drift``).
    """
    d = random_sine_sum(rng, 2, 3, 0.02, 0.12, std=[1.0, 1.0])(np.asarray(t_s, float))
    g = np.ones((len(t_s), 3))
    g[:, 0] = 1.0 + effects.wb_drift * np.tanh(d[:, 0])
    g[:, 2] = 1.0 + effects.wb_drift * np.tanh(d[:, 1])
    return g
