"""Board motion of the demo session: calibration-still poses and the hand-held video trajectory.

All poses are ``T_C_B`` (board frame B into the camera optical frame C, metres), so that the
field of view is easy to cover; the Vicon side is derived from them in ``cvsflow.synth.session``.
Every random choice comes from an explicit ``numpy.random.Generator``.

The sync gesture (the chapter's forward tilt) turns the board about its own x axis, top edge
towards the camera. With the board facing the camera that axis is C's x axis, so in
``truth_frames`` it shows as a change of ``roll_rad`` (R_C_B = Rz Ry Rx); in the Vicon world it
is a turn about the horizontal axis across the view (a pitch for a W-aligned body).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cvsflow.synth.camera import project_points
from cvsflow.transforms import R_from_euler, make_T

# The chapter's session: board held still, then tilted forward (the sync gesture), then free.
HOLD_S = 1.5
GESTURE_S = 1.0
BLEND_S = 1.0
GESTURE_TILT_RAD = np.deg2rad(25.0)


@dataclass(frozen=True)
class SineSum:
    """A smooth random signal: sum of sinusoids, shape of each array (n_channels, n_terms)."""

    amplitude: np.ndarray
    freq_hz: np.ndarray
    phase_rad: np.ndarray

    def __call__(self, t_s):
        """Evaluate all channels at times ``t_s`` (shape (N,)); returns shape (N, n_channels)."""
        t_s = np.asarray(t_s, dtype=float)
        arg = 2.0 * np.pi * self.freq_hz[None] * t_s[:, None, None] + self.phase_rad[None]
        return np.sum(self.amplitude[None] * np.sin(arg), axis=-1)


def random_sine_sum(rng, n_channels, n_terms, f_min_hz, f_max_hz, std):
    """Random sinusoid sums with stationary standard deviation ``std`` per channel.

    Amplitudes fall off as 1/f, as hand motion does, so that slow sweeps dominate and faster
    terms add the occasional quick move.
    """
    freq_hz = rng.uniform(f_min_hz, f_max_hz, size=(n_channels, n_terms))
    amplitude = rng.uniform(0.5, 1.0, size=(n_channels, n_terms)) / freq_hz
    phase_rad = rng.uniform(0.0, 2.0 * np.pi, size=(n_channels, n_terms))
    # A sum of sinusoids with amplitudes A_k has variance sum(A_k^2) / 2.
    scale = np.asarray(std, dtype=float).reshape(-1, 1) / np.sqrt(
        0.5 * np.sum(amplitude**2, axis=1, keepdims=True)
    )
    return SineSum(amplitude * scale, freq_hz, phase_rad)


@dataclass(frozen=True)
class HandMotion:
    """Parameters of the hand-held board motion (see ``board_poses``).

    ``free`` drives six channels: horizontal and vertical position of the board centre in
    units of the half field of view, log-depth, roll, pitch, yaw. ``tremor`` drives six more:
    position (m) and angle (rad) jitter of the hand.
    """

    free: SineSum
    tremor: SineSum
    hold: np.ndarray  # (6,) the channels while the board is held still
    tan_half_fov: tuple[float, float]  # (x, y)
    center_B: np.ndarray  # (3,) the point of the board the hand moves (centre of the corners)


def make_hand_motion(rng, K, size, center_B) -> HandMotion:
    """Draw a hand motion for a camera ``K`` (3x3, px) and image ``size`` (width, height) px.

    Parameters
    ----------
    rng : numpy.random.Generator
    K : ndarray, shape (3, 3)
        Camera matrix, pixels.
    size : tuple of int
        Image (width, height), pixels.
    center_B : ndarray, shape (3,)
        Point of the board (frame B, metres) that the motion channels place; the board
        turns about it.

    Returns
    -------
    HandMotion
    """
    width, height = size
    tan_half_fov = (0.5 * width / K[0, 0], 0.5 * height / K[1, 1])
    # Channels: x, y (field units), depth, roll, pitch, yaw. The stds are chosen (with the
    # tanh squashing in board_poses) so that the board is in view most of the time but
    # sometimes leaves it, and depths span 1-4 m.
    free = random_sine_sum(rng, 6, 5, 0.04, 0.5, std=[0.5, 0.45, 0.8, 0.7, 0.7, 0.6])
    tremor_std = [4e-4, 4e-4, 4e-4, np.deg2rad(0.08), np.deg2rad(0.08), np.deg2rad(0.08)]
    tremor = random_sine_sum(rng, 6, 4, 5.0, 11.0, std=tremor_std)
    hold = np.array(
        [
            rng.uniform(-0.15, 0.15),
            rng.uniform(-0.15, 0.15),
            rng.uniform(-0.3, -0.1),
            np.deg2rad(rng.uniform(-5, 5)),
            np.deg2rad(rng.uniform(-8, 8)),
            np.deg2rad(rng.uniform(-5, 5)),
        ]
    )
    return HandMotion(free, tremor, hold, tan_half_fov, np.asarray(center_B, dtype=float))


def _smoothstep(u):
    """0 below 0, 1 above 1, C1-smooth in between."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def motion_channels(motion: HandMotion, t_s):
    """The six motion channels at video times ``t_s`` (s, shape (N,)); returns shape (N, 6).

    Before ``HOLD_S`` the board is still (also for t < 0, when only the Vicon records), then it
    is tilted forward about its x axis and back (``GESTURE_S``), then blended into free motion.
    """
    t_s = np.asarray(t_s, dtype=float)
    free = motion.free(t_s)
    squashed = np.empty_like(free)
    squashed[:, 0] = 1.1 * np.tanh(free[:, 0])
    squashed[:, 1] = 1.0 * np.tanh(free[:, 1])
    squashed[:, 2] = 0.7 * np.tanh(free[:, 2])  # log-depth about 2 m: 1.0 .. 4.0 m
    squashed[:, 3] = np.deg2rad(40.0) * np.tanh(free[:, 3])
    squashed[:, 4] = np.deg2rad(45.0) * np.tanh(free[:, 4])
    squashed[:, 5] = np.deg2rad(45.0) * np.tanh(free[:, 5])
    w = _smoothstep((t_s - HOLD_S - GESTURE_S) / BLEND_S)[:, None]
    channels = (1.0 - w) * motion.hold[None] + w * squashed
    u = np.clip((t_s - HOLD_S) / GESTURE_S, 0.0, 1.0)
    channels[:, 3] += GESTURE_TILT_RAD * 0.5 * (1.0 - np.cos(2.0 * np.pi * u))
    return channels


def board_poses(motion: HandMotion, t_s):
    """True board poses T_C_B at video times ``t_s``.

    Parameters
    ----------
    motion : HandMotion
    t_s : ndarray, shape (N,)
        Video time, seconds (t = 0 at the first video frame; negative times are allowed).

    Returns
    -------
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera optical frame, metres.
    """
    ch = motion_channels(motion, t_s)
    tremor = motion.tremor(t_s)
    z_m = 2.0 * np.exp(ch[:, 2])
    center_C = np.stack(
        [
            ch[:, 0] * motion.tan_half_fov[0] * z_m,
            ch[:, 1] * motion.tan_half_fov[1] * z_m,
            z_m,
        ],
        axis=1,
    )
    center_C = center_C + tremor[:, :3]
    R_C_B = R_from_euler(ch[:, 3:6] + tremor[:, 3:6])
    t_C_B = center_C - (R_C_B @ motion.center_B)
    return make_T(R_C_B, t_C_B)


def still_poses(rng, n, K, dist, size, outline_B, margin_px=10.0, max_tries=20000):
    """Varied board poses for calibration stills, each with the printed area wholly in view.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Number of stills.
    K, dist : ndarray
        Camera matrix (3, 3) px and distortion (5,) (k1, k2, p1, p2, k3).
    size : tuple of int
        Image (width, height), px.
    outline_B : ndarray, shape (M, 3)
        Points of the board (frame B, m) that must all be inside the image.
    margin_px : float
        Minimum distance of those points from the image border, px.

    Returns
    -------
    T_C_B : ndarray, shape (n, 4, 4)
        Poses, metres; distances 0.8-2.5 m, tilts up to 50 degrees, board centres spread
        over the image with a share near its corners.
    """
    width, height = size
    center_B = outline_B.mean(axis=0)
    poses = []
    for _ in range(max_tries):
        if len(poses) == n:
            break
        z_m = rng.uniform(0.8, 2.5)
        if rng.uniform() < 0.35:
            # aim near an image corner: calibration needs the distorted periphery
            u = rng.choice([0.15, 0.85]) * width + rng.normal(0, 20)
            v = rng.choice([0.15, 0.85]) * height + rng.normal(0, 20)
        else:
            u, v = rng.uniform(0.1, 0.9) * width, rng.uniform(0.1, 0.9) * height
        x_n, y_n = (u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]
        tilt = np.deg2rad(rng.uniform(0.0, 50.0))
        axis_angle = rng.uniform(0.0, 2.0 * np.pi)
        rpy = [tilt * np.cos(axis_angle), tilt * np.sin(axis_angle), rng.uniform(-0.5, 0.5)]
        R_C_B = R_from_euler(rpy)
        t_C_B = np.array([x_n * z_m, y_n * z_m, z_m]) - R_C_B @ center_B
        T_C_B = make_T(R_C_B, t_C_B)
        uv = project_points(T_C_B, outline_B, K, dist)
        if np.all(np.isfinite(uv)) and (
            uv[:, 0].min() >= margin_px
            and uv[:, 1].min() >= margin_px
            and uv[:, 0].max() <= width - 1 - margin_px
            and uv[:, 1].max() <= height - 1 - margin_px
        ):
            poses.append(T_C_B)
    return np.array(poses)
