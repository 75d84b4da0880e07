"""A rendered multi-camera session as data: N cameras on one camera-marker body, one board.

A rig session (``config["sessions"][name]`` with a ``cameras:`` list) is rendered camera by
camera with the mono renderer: each camera is a mono session (:func:`camera_session_config`,
its own intrinsics, image size, frame rate, stills and image noise) whose board motion is the
rig's one hand motion seen from that camera (:class:`cvsflow.synth.motion.CameraView`), on
its own clock. Camera 0 is the reference: the rig's geometry is the mono rig of camera 0
(:func:`cvsflow.synth.session.make_rig`: marker placement, the level camera, camera 0's time
offset), the hand motion is drawn for camera 0's view, and the Vicon export is the mono
recording of camera 0's session (:func:`rig_vicon_recording`). Camera i sits at its designed
mounting ``T_Cm_Ci`` corrected as camera 0's is by the marker placement error (the true Cm
is the fit of the layout to the real markers), and its clock runs ``clock_offset_s`` behind
camera 0's: ``dt_offset_s,i = dt_offset_s,0 + clock_offset_s,i`` (t_vicon = t_video,i +
dt_offset_s,i). The board is seen by one camera, several or none, as the hand moves it.

Pure functions of the session config (no file I/O); :mod:`cvsflow.synth.render` writes
``data/{rig}/vicon.csv``, ``data/{rig}/truth.yaml`` and each camera's ``data/{rig}/{camera}/``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from cvsflow.exceptions import ConfigError
from cvsflow.geometry import invert_T
from cvsflow.synth.motion import CameraView, HandMotion, board_poses, make_hand_motion
from cvsflow.synth.session import Rig, make_rig, vicon_recording
from cvsflow.synth.spec import VICON_RATE_HZ, SynthSpec, parse_session_config, random_streams
from cvsflow.synth.stereo import shared_view_poses

#: Keys of a rig camera's ``synth`` block (the others are the rig's ``synth`` keys).
RIG_CAMERA_SYNTH_KEYS = (
    "camera", "T_Cm_C_pose6", "fps", "image_size", "clock_offset_s", "n_stills",
    "image_noise_sigma", "video_quality",
)
#: Keys of the rig's own ``synth`` block that no camera inherits.
RIG_SYNTH_ONLY_KEYS = ("n_shared_stills",)
#: Shared views (stills every camera sees whole at one instant) rendered by default.
DEFAULT_SHARED_STILLS = 12


def _cameras(session_cfg):
    cams = session_cfg.get("cameras") if isinstance(session_cfg, dict) else None
    if not isinstance(cams, list) or not cams:
        raise ConfigError("rig session config: expected a non-empty 'cameras' list")
    return cams


def camera_session_config(session_cfg: dict, index: int) -> dict:
    """The mono session block that renders camera ``index`` of a rig session.

    Parameters
    ----------
    session_cfg : dict
        The rig session: ``synth`` (the mono keys shared by every camera: seed, duration,
        ``T_Bm_B_pose6``, marker noise, ``mocap_lead_s``, ...; ``n_shared_stills``), ``board``,
        ``markers`` and ``cameras`` (per camera ``name`` and a ``synth`` block of
        ``RIG_CAMERA_SYNTH_KEYS``: ``camera`` intrinsics, ``T_Cm_C_pose6``, ``fps`` (Hz),
        ``image_size`` ([w, h] px), ``clock_offset_s`` (s), ``n_stills``, ...).
    index : int
        The camera, 0 first.

    Returns
    -------
    dict
        ``{"synth", "board", "markers"}`` for :func:`cvsflow.synth.spec.parse_session_config`:
        the rig's ``synth`` keys overridden by the camera's (``clock_offset_s`` left out).

    Raises
    ------
    ConfigError
        No ``cameras`` list, ``index`` out of range, a camera without ``synth`` or with an
        unknown key.
    """
    cams = _cameras(session_cfg)
    if not 0 <= index < len(cams):
        raise ConfigError(f"rig session config: camera {index}; the rig has {len(cams)} cameras")
    entry = cams[index]
    name = entry.get("name", index) if isinstance(entry, dict) else index
    own = entry.get("synth") if isinstance(entry, dict) else None
    if not isinstance(own, dict):
        raise ConfigError(f"rig session config, cameras[{name}]: expected a synth block")
    unknown = sorted(set(own) - set(RIG_CAMERA_SYNTH_KEYS))
    if unknown:
        raise ConfigError(
            f"rig session config, cameras[{name}].synth: unknown keys {unknown} "
            f"(expected some of {list(RIG_CAMERA_SYNTH_KEYS)})"
        )
    synth = {k: v for k, v in dict(session_cfg.get("synth") or {}).items() if k not in RIG_SYNTH_ONLY_KEYS}
    synth.update({k: v for k, v in own.items() if k != "clock_offset_s"})
    return {"synth": synth, "board": session_cfg.get("board"), "markers": session_cfg.get("markers")}


@dataclass(frozen=True)
class RigTruth:
    """The true, fixed geometry of a rendered rig and the board's motion (metres, seconds)."""

    names: tuple  # camera names, camera 0 first
    specs: tuple  # SynthSpec per camera
    rig: Rig  # camera 0's mono rig: markers, T_W_Cm, T_Bm_B; T_Cm_C and dt_offset_s of camera 0
    T_Cm_C: tuple  # (4, 4) true mounting of each camera on the rig body
    dt_offset_s: tuple  # t_vicon_s = t_video_s,i + dt_offset_s[i]
    clock_offset_s: tuple  # dt_offset_s[i] - dt_offset_s[0]
    motion: HandMotion  # the board in camera 0, on camera 0's video clock
    n_shared_stills: int
    seed: int

    def T_C_C0(self, i):
        """Camera i's pose from camera 0, T_Ci_C0 (4, 4), m."""
        return invert_T(self.T_Cm_C[i]) @ self.T_Cm_C[0]

    def camera_rig(self, i) -> Rig:
        """Camera i as a mono :class:`~cvsflow.synth.session.Rig` (its mounting and offset)."""
        return replace(self.rig, T_Cm_C=self.T_Cm_C[i], dt_offset_s=self.dt_offset_s[i])

    def view(self, i):
        """The board's motion as camera i sees it on its own clock (camera 0: ``motion``)."""
        if i == 0:
            return self.motion
        return CameraView(self.motion, self.T_C_C0(i), self.dt_offset_s[i] - self.dt_offset_s[0])


def make_rig_truth(session_cfg: dict) -> RigTruth:
    """Parse a rig session and draw its true geometry and motion (deterministic in the seed).

    Parameters
    ----------
    session_cfg : dict
        The rig session (see :func:`camera_session_config`).

    Returns
    -------
    RigTruth
        Every camera's spec, true mounting and time offset, camera 0's rig and the motion.

    Raises
    ------
    ConfigError
        A bad camera block, repeated camera names, cameras with different boards, or a
        camera whose video would start before the Vicon take (``mocap_lead_s`` +
        ``clock_offset_s`` <= 0).
    """
    cams = _cameras(session_cfg)
    names = tuple(str(c.get("name", "")) for c in cams)
    if len(set(names)) != len(names) or not all(names):
        raise ConfigError(f"rig session config, cameras: names must be given and distinct, got {list(names)}")
    specs = tuple(parse_session_config(camera_session_config(session_cfg, i)) for i in range(len(cams)))
    for n, spec in zip(names, specs, strict=True):
        extra = sorted(set(spec.effects.explicit) - {"fps", "image_size", "distance_m"})
        if spec.effects.preset != "fast" or extra:
            raise ConfigError(
                f"rig session config, cameras[{n}]: a rig renders with the fast renderer "
                f"(fps, image_size and distance_m may be set); got preset "
                f"{spec.effects.preset!r} and effect keys {extra}"
            )
    spec0 = specs[0]
    rngs = random_streams(spec0.seed)
    rig = make_rig(spec0, rngs["mounting"])
    # The true Cm differs from the designed one by the marker placement error: the same
    # correction for every camera on the body.
    T_true_design = rig.T_Cm_C @ invert_T(spec0.T_Cm_C_design)
    T_Cm_C = tuple([rig.T_Cm_C] + [T_true_design @ s.T_Cm_C_design for s in specs[1:]])
    offsets = [0.0] + [float(c["synth"].get("clock_offset_s", 0.0)) for c in cams[1:]]
    if float(cams[0]["synth"].get("clock_offset_s", 0.0)) != 0.0:
        raise ConfigError(
            f"rig session config, cameras[{names[0]}].synth.clock_offset_s: camera 0 is the "
            f"reference clock; expected 0 (or absent)"
        )
    dts = tuple(rig.dt_offset_s + off for off in offsets)
    for n, dt in zip(names, dts, strict=True):
        if not dt > 0.0:
            raise ConfigError(
                f"rig session config, cameras[{n}].synth.clock_offset_s: the video would start "
                f"{-dt:.3f} s before the Vicon take; expected mocap_lead_s + clock_offset_s > 0"
            )
    motion = make_hand_motion(
        rngs["motion"], spec0.K, spec0.image_size, spec0.board.center_B(), spec0.effects.distance_m,
        R_face_B=spec0.board.R_face_B() if spec0.board.kind == "aprilgrid" else None,
    )
    n_shared = int((session_cfg.get("synth") or {}).get("n_shared_stills", DEFAULT_SHARED_STILLS))
    return RigTruth(names, specs, rig, T_Cm_C, dts, tuple(offsets), motion, n_shared, spec0.seed)


def rig_vicon_recording(truth: RigTruth):
    """The rig session's Vicon export: camera 0's mono recording, long enough for every camera.

    Parameters
    ----------
    truth : RigTruth

    Returns
    -------
    markers : DataFrame
        Wide marker table (``cvsflow.io.mocap.vicon`` form), metres, NaN in dropouts.
    T_W_Bm : ndarray, shape (N, 4, 4)
        True board-marker body poses at the Vicon samples.
    n_dropouts : int
    """
    spec0 = truth.specs[0]
    # The take must outlast the camera whose video ends last on the Vicon clock.
    longest = max(s.duration_s + off for s, off in zip(truth.specs, truth.clock_offset_s, strict=True))
    spec = replace(spec0, duration_s=max(spec0.duration_s, longest))
    return vicon_recording(spec, truth.rig, truth.motion, random_streams(truth.seed)["vicon"])


def shared_views(truth: RigTruth):
    """True board poses T_C0_B (n, 4, 4, m) of the rig's shared views, the same for every camera.

    Parameters
    ----------
    truth : RigTruth

    Returns
    -------
    T_C0_B : ndarray, shape (n_shared_stills, 4, 4)
        Empty (0, 4, 4) when ``n_shared_stills`` is 0.

    Raises
    ------
    ConfigError
        The cameras' views overlap too little to place the views.
    """
    if truth.n_shared_stills <= 0:
        return np.zeros((0, 4, 4))
    rng = np.random.default_rng(np.random.SeedSequence([truth.seed, 0]))
    cameras = [(s.K, s.dist, s.image_size) for s in truth.specs]
    T_Ci_C0 = [truth.T_C_C0(i) for i in range(len(truth.specs))]
    return shared_view_poses(rng, truth.n_shared_stills, cameras, T_Ci_C0, truth.specs[0].board)


def true_board_poses_C0(truth: RigTruth, t_vicon_s):
    """The true board pose in camera 0, T_C0_B (N, 4, 4, m), at Vicon times ``t_vicon_s`` (s).

    Parameters
    ----------
    truth : RigTruth
    t_vicon_s : array_like, shape (N,)
        Times on the Vicon clock, s (a fused rig pose's ``t_vicon_s``).

    Returns
    -------
    T_C0_B : ndarray, shape (N, 4, 4)
    """
    return board_poses(truth.motion, np.asarray(t_vicon_s, float) - truth.dt_offset_s[0])


def camera_frame_times(spec: SynthSpec):
    """Video frame times (s) of one rig camera: ``duration_s * fps`` frames at its ``fps``.

    Parameters
    ----------
    spec : SynthSpec
        The camera's spec (``duration_s``, ``effects.fps``).

    Returns
    -------
    t_s : ndarray, shape (N,)
    """
    fps = float(spec.effects.fps)
    return np.arange(int(round(spec.duration_s * fps))) / fps


def rig_truth_document(truth: RigTruth, shared_T_C0_B=None) -> dict:
    """The rig's ``truth.yaml`` mapping: every camera's truth, the shared bodies and views.

    Parameters
    ----------
    truth : RigTruth
    shared_T_C0_B : ndarray, shape (n, 4, 4), optional
        The shared views' true board poses in camera 0 (:func:`shared_views`).

    Returns
    -------
    doc : dict
        ``cameras`` (per camera ``name``, ``camera`` (K, dist, width, height), ``fps``,
        ``n_frames``, ``T_Cm_C``, ``T_C0_C``, ``dt_offset_s``, ``clock_offset_s``), ``T_Bm_B``,
        ``T_W_Cm``, ``markers_Cm_m``, ``markers_Bm_m``, ``board``, ``seed``, ``duration_s``,
        ``vicon_rate_hz`` and ``shared_views`` (``T_C0_B``); numpy arrays not yet converted.
    """
    rig = truth.rig
    spec0 = truth.specs[0]
    cams = []
    for i, (name, spec) in enumerate(zip(truth.names, truth.specs, strict=True)):
        width, height = spec.image_size
        cams.append({
            "name": name,
            "camera": {"K": spec.K, "dist": spec.dist, "width": int(width), "height": int(height)},
            "fps": float(spec.effects.fps),
            "n_frames": len(camera_frame_times(spec)),
            "T_Cm_C": truth.T_Cm_C[i],
            "T_C0_C": invert_T(truth.T_C_C0(i)),
            "dt_offset_s": float(truth.dt_offset_s[i]),
            "clock_offset_s": float(truth.clock_offset_s[i]),
        })
    return {
        "cameras": cams,
        "T_Bm_B": rig.T_Bm_B,
        "T_W_Cm": rig.T_W_Cm,
        "markers_Cm_m": dict(zip(spec0.camera_names, rig.markers_Cm_m, strict=True)),
        "markers_Bm_m": dict(zip(spec0.board_names, rig.markers_Bm_m, strict=True)),
        "board": spec0.board.config(),
        "seed": truth.seed,
        "duration_s": spec0.duration_s,
        "vicon_rate_hz": VICON_RATE_HZ,
        "shared_views": {"T_C0_B": np.zeros((0, 4, 4)) if shared_T_C0_B is None else shared_T_C0_B},
    }
