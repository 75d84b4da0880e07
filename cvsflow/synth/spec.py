"""The demo session's configuration as data: sizes, rates, the parsed spec and its random streams.

Pure functions of the session config (no file I/O). The session's truth (rig, poses, Vicon
recording) is :mod:`cvsflow.synth.session`'s, its images :mod:`cvsflow.synth.frames`'.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cvsflow.board import aprilgrid_from_board, board_type, charuco_board
from cvsflow.exceptions import ConfigError
from cvsflow.geometry import T_from_pose6
from cvsflow.synth.effects import Effects, parse_effects
from cvsflow.synth.imaging import Board, aprilgrid_board, camera_from_config
from cvsflow.synth.motion import CAMERA_MOTION_TYPES, CameraMotion

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
    mocap_lead_s: float
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
    if board_type(board_cfg) == "aprilgrid":
        board = aprilgrid_board(aprilgrid_from_board(board_cfg))
    else:
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
    effects = parse_effects(synth, image_noise_sigma, video_quality)
    if board.kind == "aprilgrid" and effects.occlusion:
        raise ConfigError("session config, synth.occlusion: the hand is drawn over a chessboard's "
                          "squares only; set occlusion: {enabled: false} for an AprilGrid session")
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
        mocap_lead_s=float(synth.get("mocap_lead_s", 2.37)),
        image_noise_sigma=image_noise_sigma,
        video_quality=video_quality,
        effects=effects,
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
