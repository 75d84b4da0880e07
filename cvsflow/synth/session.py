"""The demo session's truth as data: the rig, true poses, exposure times and the Vicon recording.

Pure functions of the session spec (:mod:`cvsflow.synth.spec`; no file I/O); the images are
:mod:`cvsflow.synth.frames`'. ``cvsflow.synth.render.render_session`` writes their results with
``cvsflow.io.synth_out``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from cvsflow.geometry import euler_from_R, invert_T, quat_from_R, transform_points
from cvsflow.synth.imaging import Board, project_in_view, rectangle_outline_B
from cvsflow.synth.markers import add_dropouts, marker_table, true_mounting
from cvsflow.synth.motion import HandMotion, board_poses, camera_poses, random_sine_sum
from cvsflow.synth.spec import FPS, IN_VIEW_MARGIN_PX, VICON_RATE_HZ, VICON_TAIL_S, SynthSpec


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
    the Vicon axes by hand (a few degrees off). The true time offset is ``mocap_lead_s``
    plus a random fraction of a Vicon sample, so it is never a whole number of samples.

    Parameters
    ----------
    spec : SynthSpec
        The designed mountings, marker layouts (m), placement error sigma (m) and
        ``mocap_lead_s`` (s).
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
    return Rig(T_W_Cm, T_Cm_C, T_Bm_B, markers_Cm, markers_Bm, spec.mocap_lead_s + sub_sample_s)


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
    corners_px = project_in_view(T_C_B, corners_B, spec.K, spec.dist)
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
    start = project_in_view(board_poses(motion, t_s - exposure_s / 2), corners_B, spec.K, spec.dist)
    stop = project_in_view(board_poses(motion, t_s + exposure_s / 2), corners_B, spec.K, spec.dist)
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
        uv = project_in_view(np.eye(4), p_C.reshape(-1, 3), K, dist).reshape(n, m, 2)
    v = np.nan_to_num(uv[..., 1], nan=0.0)
    return uv, t_s[:, None] + np.clip(v, 0, None) * line_delay_s


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
        Wide marker table (``cvsflow.io.mocap.vicon`` form), metres, NaN in dropouts.
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
