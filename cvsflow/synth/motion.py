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

from cvsflow.geometry import R_from_euler, R_from_rvec, invert_T, make_T
from cvsflow.synth.imaging import project_in_view

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

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the frequencies, amplitudes and phases.
    n_channels : int
        Independent signals.
    n_terms : int
        Sinusoids per signal.
    f_min_hz, f_max_hz : float
        Range of the (uniform) frequencies, Hz.
    std : array_like, shape (n_channels,)
        Standard deviation of each channel over time, in the channel's own unit.

    Returns
    -------
    SineSum
        Callable: times (N,) in s to values (N, n_channels), zero mean.
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
    depth_center_m: float = 2.0  # geometric centre of the depth range, m
    depth_half_log: float = 0.7  # half width of the log-depth range (depth = centre exp(+-this))
    # (3, 3) B to the board's face-on frame (Board.R_face_B) when it is not the identity: the
    # channels turn the face-on frame, so an AprilGrid (z out of its face) faces the camera too.
    R_face_B: np.ndarray | None = None


def make_hand_motion(rng, K, size, center_B, distance_m=None, R_face_B=None) -> HandMotion:
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
    distance_m : tuple of float, optional
        (min, max) depth of the board centre, m; by default the demo's 1.0 .. 4.0 m.
    R_face_B : ndarray, shape (3, 3), optional
        ``Board.R_face_B`` of a board whose frame is not face-on (an AprilGrid); None: B is.

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
    if distance_m is None:
        return HandMotion(free, tremor, hold, tan_half_fov, np.asarray(center_B, dtype=float),
                          R_face_B=R_face_B)
    d_min, d_max = distance_m
    return HandMotion(
        free, tremor, hold, tan_half_fov, np.asarray(center_B, dtype=float),
        depth_center_m=float(np.sqrt(d_min * d_max)), depth_half_log=float(0.5 * np.log(d_max / d_min)),
        R_face_B=R_face_B,
    )


def _smoothstep(u):
    """0 below 0, 1 above 1, C1-smooth in between."""
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def motion_channels(motion: HandMotion, t_s):
    """The six motion channels at video times ``t_s`` (s, shape (N,)); returns shape (N, 6).

    Before ``HOLD_S`` the board is still (also for t < 0, when only the Vicon records), then it
    is tilted forward about its x axis and back (``GESTURE_S``), then blended into free motion.

    Parameters
    ----------
    motion : HandMotion
        The motion's random signals and hold pose.
    t_s : array_like, shape (N,)
        Video-clock times, s (negative ones are before the video starts).

    Returns
    -------
    channels : ndarray, shape (N, 6)
        Per time: horizontal and vertical position of the board centre in units of the half
        field of view (``tan_half_fov``), log-depth relative to ``depth_center_m``
        (dimensionless), and roll, pitch, yaw (rad).
    """
    t_s = np.asarray(t_s, dtype=float)
    free = motion.free(t_s)
    squashed = np.empty_like(free)
    squashed[:, 0] = 1.1 * np.tanh(free[:, 0])
    squashed[:, 1] = 1.0 * np.tanh(free[:, 1])
    squashed[:, 2] = motion.depth_half_log * np.tanh(free[:, 2])  # log-depth: 1.0 .. 4.0 m (demo)
    squashed[:, 3] = np.deg2rad(40.0) * np.tanh(free[:, 3])
    squashed[:, 4] = np.deg2rad(45.0) * np.tanh(free[:, 4])
    squashed[:, 5] = np.deg2rad(45.0) * np.tanh(free[:, 5])
    w = _smoothstep((t_s - HOLD_S - GESTURE_S) / BLEND_S)[:, None]
    channels = (1.0 - w) * motion.hold[None] + w * squashed
    u = np.clip((t_s - HOLD_S) / GESTURE_S, 0.0, 1.0)
    channels[:, 3] += GESTURE_TILT_RAD * 0.5 * (1.0 - np.cos(2.0 * np.pi * u))
    return channels


@dataclass(frozen=True)
class CameraView:
    """The hand motion as another camera of a rig sees it, on that camera's own clock.

    ``T_C_B(t) = T_C_C0 T_C0_B(t + t_shift_s)``: ``motion`` is the board's motion in the
    reference camera C0 on C0's video clock, ``T_C_C0`` (4, 4, m) this camera's pose from C0,
    and ``t_shift_s`` = ``dt_offset_s`` of this camera less C0's (s), so that this camera's
    video time t is C0's video time t + ``t_shift_s`` (the same Vicon instant).
    """

    motion: HandMotion
    T_C_C0: np.ndarray
    t_shift_s: float


@dataclass(frozen=True)
class PoseTrack:
    """A board motion given as a function of time: ``T_C_B(t_s)`` (N,) s -> (N, 4, 4), m.

    What a trajectory made elsewhere (a rendered flight's body carrying the board,
    :func:`cvsflow.synth.flight_video.render_flight_video`) gives the renderer, whose motion
    blur, rolling shutter and exposure sample it at any time.
    """

    T_C_B: object


def board_poses(motion: HandMotion | CameraView | PoseTrack, t_s):
    """True board poses T_C_B at video times ``t_s``.

    Parameters
    ----------
    motion : HandMotion, CameraView or PoseTrack
        The board's motion in the camera (a :class:`CameraView`: in another camera of a rig;
        a :class:`PoseTrack`: any function of time).
    t_s : ndarray, shape (N,)
        Video time, seconds (t = 0 at the first video frame; negative times are allowed).

    Returns
    -------
    T_C_B : ndarray, shape (N, 4, 4)
        Board in the camera optical frame, metres.
    """
    if isinstance(motion, CameraView):
        return motion.T_C_C0 @ board_poses(motion.motion, np.asarray(t_s, dtype=float) + motion.t_shift_s)
    if isinstance(motion, PoseTrack):
        return np.asarray(motion.T_C_B(np.atleast_1d(np.asarray(t_s, dtype=float))), dtype=float)
    ch = motion_channels(motion, t_s)
    tremor = motion.tremor(t_s)
    z_m = motion.depth_center_m * np.exp(ch[:, 2])
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
    if motion.R_face_B is not None:
        R_C_B = R_C_B @ motion.R_face_B
    t_C_B = center_C - (R_C_B @ motion.center_B)
    return make_T(R_C_B, t_C_B)


# Calibration stills: a stratified plan as the OpenCV calibration tutorial advises. The image
# is split into a 3x3 grid of regions; one still pushes the board into each region (the four
# corners first, where the lens distorts most, then the four edges, then the centre), and the
# remaining stills are strongly tilted views about the board's x axis, its y axis and both,
# spread over the outer regions. Every board is wholly in view with a margin and its squares
# stay large enough for sub-pixel refinement.
_CELL_PUSH = ((-1, -1), (1, -1), (-1, 1), (1, 1), (0, -1), (1, 0), (0, 1), (-1, 0), (0, 0))
# (axis angle in the board plane, degrees): about board x, about board y, about both.
_TILT_AXES_DEG = (0.0, 90.0, 45.0, 135.0)
_CELL_DEPTH_M = {2: (1.5, 2.1), 1: (1.1, 1.7), 0: (0.8, 1.0)}  # by number of pushed axes
_CELL_TILT_DEG = (10.0, 35.0)
_TILTED_DEPTH_M = (0.7, 1.1)
_TILTED_TILT_DEG = (40.0, 50.0)
_IN_PLANE_RAD = 0.3


def _depth_range(depth_m, z_cap_m):
    """``depth_m`` (lo, hi) with hi at most ``z_cap_m``, lo kept below it, m.

    The ranges above suit the demo's camera and board; a wider lens or smaller squares cap the
    depth at which a square still spans ``min_square_px`` (``still_poses``)."""
    lo, hi = depth_m
    if hi <= z_cap_m:
        return lo, hi
    return min(lo, 0.75 * z_cap_m), z_cap_m


def still_plan(rng, n):
    """The strata of ``n`` calibration stills: one (push, tilt axis or None) per still.

    ``push`` = (sx, sy) in {-1, 0, 1}^2 is the image region the board is pushed into (x right,
    y down); a tilt axis (radians, in the board plane from board x) marks a strongly tilted
    view, None a moderately tilted one of random axis. The first min(n, 9) stills visit the
    3x3 regions (corners, edges, centre); the rest are tilted views over the outer regions.

    Parameters
    ----------
    rng : numpy.random.Generator
        Permutes the outer regions for the tilted views.
    n : int
        Number of stills.

    Returns
    -------
    plan : list of (tuple of int, float or None)
        ``n`` entries ``((sx, sy), axis_rad)``, in still order.
    """
    plan = [(push, None) for push in _CELL_PUSH[: min(n, 9)]]
    outer = list(_CELL_PUSH[:8])
    pushes = [outer[i] for i in rng.permutation(len(outer))]
    for k in range(n - len(plan)):
        axis = np.deg2rad(_TILT_AXES_DEG[k % len(_TILT_AXES_DEG)])
        plan.append((pushes[k % len(pushes)], axis))
    return plan


def _in_view(uv, size, margin_px):
    width, height = size
    return bool(
        np.all(np.isfinite(uv))
        and uv[:, 0].min() >= margin_px
        and uv[:, 1].min() >= margin_px
        and uv[:, 0].max() <= width - 1 - margin_px
        and uv[:, 1].max() <= height - 1 - margin_px
    )


def _min_square_px(T_C_B, board_corners, K, dist):
    """Shortest projected side between neighbouring corners, px (inf without a board);
    ``board_corners`` = ``(corners_B, *board.edge_pairs())``."""
    if board_corners is None:
        return np.inf
    corners_B, a, b = board_corners
    g = project_in_view(T_C_B, corners_B, K, dist)
    sides = np.linalg.norm(g[b] - g[a], axis=-1)
    return float(np.min(sides)) if np.all(np.isfinite(sides)) else 0.0


def _push_into_region(fits, push, limit, back_off):
    """Board centre (normalised x, y) pushed towards the image region ``push`` while in view.

    ``fits(x_n, y_n)`` tells whether that placement is wholly in view; the feasible set is
    close to convex, so pushing diagonally and then along each axis in turn (bisection) finds
    its extreme point in the ``push`` direction. ``back_off`` (0..1) then moves the board that
    fraction back towards the image centre. Returns None when even the centre does not fit.
    """
    p = np.zeros(2)
    if not fits(*p):
        return None
    directions = [np.asarray(push, dtype=float)] + [
        np.eye(2)[a] * push[a] for a in (0, 1, 0, 1, 0, 1) if push[a] != 0
    ]
    for d in directions:
        if not np.any(d):
            continue
        lo, hi = 0.0, limit  # lo fits, hi is far outside the field of view
        for _ in range(30):
            mid = 0.5 * (lo + hi)
            if fits(*(p + mid * d)):
                lo = mid
            else:
                hi = mid
        p = p + lo * d
    return (1.0 - back_off) * p


def still_poses(
    rng, n, K, dist, size, outline_B, margin_px=10.0, board=None, min_square_px=20.0,
    max_tries=200,
):
    """Board poses for ``n`` calibration stills that together cover the whole image.

    A careful user's calibration set (``still_plan``): boards pushed into each region of a 3x3
    grid of the image, corners and edges included, at several distances and tilts, then
    strongly tilted views (40-50 degrees about the board's x axis, its y axis, and both).
    Deterministic for a given generator state.

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
    board : Board, optional
        When given, every projected side between neighbouring inner corners must be at least
        ``min_square_px`` long, so that corner detection and sub-pixel refinement stay exact.
    min_square_px : float
        See ``board``.
    max_tries : int
        Random draws per still before giving up on it.

    Returns
    -------
    T_C_B : ndarray, shape (k, 4, 4)
        Poses, metres, k <= n (fewer only when the board cannot be placed as planned);
        distances 0.7-2.1 m (nearer where a wide lens or small squares need it; a still tries
        ``max_tries`` draws at the nominal depths, then as many capped), tilts 10-50 degrees,
        in-plane turns up to 17 degrees.

    Notes
    -----
    Below ~18 px per square, ``cornerSubPix`` with the calibration's 11 px half window reaches
    the neighbouring corners and lands pixels off (random poses without this check gave
    calibration RMS 0.5-1.4 px and focal errors of 2-3 % for 4 of 10 seeds).
    """
    width, height = size
    center_B = outline_B.mean(axis=0)
    limit = 2.0 * max(width / K[0, 0], height / K[1, 1])  # normalised, beyond any fit
    board_corners = None if board is None else (board.corners_B(), *board.edge_pairs())
    # An AprilGrid's frame is turned against its face (z out of it): the views turn its face.
    R_face_B = board.R_face_B() if board is not None and board.kind == "aprilgrid" else None
    # Deepest board whose squares (foreshortened by the largest tilt) keep min_square_px: used
    # only for a still the nominal depths cannot place, so sessions that render keep their draws.
    z_cap_m = np.inf
    if board is not None:
        z_cap_m = 0.95 * min(K[0, 0], K[1, 1]) * board.square_m / min_square_px
    z_caps_m = (np.inf, z_cap_m * np.cos(np.deg2rad(_CELL_TILT_DEG[1])))
    z_caps_tilted_m = (np.inf, z_cap_m * np.cos(np.deg2rad(_TILTED_TILT_DEG[1])))
    poses = []
    for push, tilt_axis in still_plan(rng, n):
        for attempt in range(2 * max_tries):
            capped = attempt // max_tries
            if tilt_axis is None:
                depth_m = _depth_range(_CELL_DEPTH_M[int(np.count_nonzero(push))], z_caps_m[capped])
                z_m = rng.uniform(*depth_m)
                axis = rng.uniform(0.0, 2.0 * np.pi)
                tilt = np.deg2rad(rng.uniform(*_CELL_TILT_DEG))
            else:
                z_m = rng.uniform(*_depth_range(_TILTED_DEPTH_M, z_caps_tilted_m[capped]))
                axis = tilt_axis + (np.pi if rng.uniform() < 0.5 else 0.0)
                tilt = np.deg2rad(rng.uniform(*_TILTED_TILT_DEG))
            in_plane = rng.uniform(-_IN_PLANE_RAD, _IN_PLANE_RAD)
            back_off = rng.uniform(0.0, 0.08)
            # Tilt about an axis in the board plane, then turn the board about the view axis.
            R_C_B = R_from_euler([0.0, 0.0, in_plane]) @ R_from_rvec(
                tilt * np.array([np.cos(axis), np.sin(axis), 0.0])
            )
            if R_face_B is not None:
                R_C_B = R_C_B @ R_face_B

            # The board centre on the ray of normalised image point (x_n, y_n), at depth z_m.
            def pose(x_n, y_n, R_C_B=R_C_B, z_m=z_m):
                return make_T(R_C_B, np.array([x_n * z_m, y_n * z_m, z_m]) - R_C_B @ center_B)

            def fits(x_n, y_n, pose=pose):
                return _in_view(project_in_view(pose(x_n, y_n), outline_B, K, dist), size, margin_px)

            p = _push_into_region(fits, push, limit, back_off)
            if p is None:
                continue
            T_C_B = pose(*p)
            if fits(*p) and _min_square_px(T_C_B, board_corners, K, dist) >= min_square_px:
                poses.append(T_C_B)
                break
    return np.array(poses)


# Camera motion (config ``synth.camera_motion``). The image of every frame depends only on the
# relative pose T_C_B(t) (``board_poses``), so a moving camera changes the Vicon recording and
# the truth, never the video: a moving-camera session and the fixed-camera one of the same
# seed see the same images.
CAMERA_MOTION_TYPES = ("static", "handheld", "orbit")


@dataclass(frozen=True)
class CameraMotion:
    """How the camera moves in the Vicon world W (see ``camera_poses``).

    ``static``: on its chair (the demo). ``handheld``: hand-held around a fixed board; the
    board stands where it is at video time 0 and the camera makes the whole relative motion.
    ``orbit``: on a robot swinging it about a vertical axis ``radius_m`` ahead of the lens by
    ``amplitude_rad * sin(2 pi t / period_s)``, rising and falling by ``lift_m`` at twice that
    rate; the board is hand-held as in the demo, so it is carried round with the camera
    (both bodies move in W).
    """

    type: str = "static"
    radius_m: float = 2.0
    amplitude_rad: float = 0.35
    period_s: float = 8.0
    lift_m: float = 0.1

    @property
    def moving(self) -> bool:
        return self.type != "static"

    def as_dict(self):
        """The config form (for truth.yaml)."""
        return {"type": self.type, "radius_m": self.radius_m, "amplitude_rad": self.amplitude_rad,
                "period_s": self.period_s, "lift_m": self.lift_m}  # fmt: skip


def camera_poses(camera_motion: CameraMotion, hand: HandMotion, T_W_C0, t_s):
    """True camera optical frame in W, T_W_C, at video times ``t_s``.

    Parameters
    ----------
    camera_motion : CameraMotion
    hand : HandMotion
        The relative motion (``board_poses``); a hand-held camera carries all of it.
    T_W_C0 : ndarray, shape (4, 4)
        The camera's pose when static (the rig on its chair), metres.
    t_s : ndarray, shape (N,)
        Video time, s (negative before the video, while the Vicon records).

    Returns
    -------
    T_W_C : ndarray, shape (N, 4, 4)
        Metres; ``T_W_C0`` at every time for a static camera. For ``handheld``,
        T_W_C(t) = T_W_C0 T_C_B(0) inv(T_C_B(t)) (the board still at T_W_C0 T_C_B(0)); for
        ``orbit``, T_W_C0 turned about the vertical through the pivot and lifted.
    """
    t_s = np.atleast_1d(np.asarray(t_s, dtype=float))
    T_W_C0 = np.asarray(T_W_C0, dtype=float)
    if camera_motion.type == "static":
        return np.repeat(T_W_C0[None], len(t_s), axis=0)
    if camera_motion.type == "handheld":
        T_W_B = T_W_C0 @ board_poses(hand, np.zeros(1))[0]
        return T_W_B @ invert_T(board_poses(hand, t_s))
    if camera_motion.type == "orbit":
        phase = 2.0 * np.pi * t_s / camera_motion.period_s
        theta = camera_motion.amplitude_rad * np.sin(phase)
        pivot_W = T_W_C0[:3, 3] + camera_motion.radius_m * T_W_C0[:3, 2]
        Rz = R_from_euler(np.stack([np.zeros_like(theta), np.zeros_like(theta), theta], axis=1))
        p_W = pivot_W + np.einsum("nij,j->ni", Rz, T_W_C0[:3, 3] - pivot_W)
        p_W[:, 2] += camera_motion.lift_m * np.sin(2.0 * phase)
        return make_T(Rz @ T_W_C0[:3, :3], p_W)
    raise ValueError(f"camera motion type {camera_motion.type!r}; expected {CAMERA_MOTION_TYPES}")
