"""Calibration stills taken at the same instants by two or more fixed cameras (shared views).

The rig's cameras each have their own session block (intrinsics, image size, noise); camera i
sits at ``T_Ci_C0`` from camera 0. A shared view is a board pose that every camera sees whole,
with squares large enough for exact corners, each camera rendering it with its own renderer
(``synth.session.Renderer``): the stills ``cvsflow.rig.extrinsics.stereo_extrinsics`` is tested on.
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import ConfigError
from cvsflow.geometry import R_from_euler, R_from_rvec, make_T
from cvsflow.synth.frames import Renderer
from cvsflow.synth.imaging import project_in_view
from cvsflow.synth.motion import _in_view, _min_square_px
from cvsflow.synth.session import still_outline_B
from cvsflow.synth.spec import parse_session_config


def shared_view_poses(rng, n, cameras, T_Ci_C0, board, depth_m=(1.2, 2.6), max_tilt_deg=35.0,
                      margin_px=10.0, min_square_px=20.0, max_tries=2000):
    """Board poses in camera 0 that every camera of the rig sees whole.

    Parameters
    ----------
    rng : numpy.random.Generator
    n : int
        Number of poses wanted.
    cameras : sequence of (K, dist, size)
        Each camera's matrix (3, 3) px, distortion (5,) and image (width, height) px.
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0 (identity first), metres.
    board : synth Board
        The printed board (its outline must be in view, its squares at least
        ``min_square_px`` long in every camera).
    depth_m : (float, float)
        Range of the board centre's depth in camera 0, m.
    max_tilt_deg : float
        Largest tilt of the board from facing camera 0 (about an axis in the board plane); it
        also turns up to 20 degrees about camera 0's view axis.
    margin_px, min_square_px : float
        Distance of the outline from every image border, and shortest square side, px.
    max_tries : int
        Random draws before giving up.

    Returns
    -------
    T_C0_B : ndarray, shape (n, 4, 4)
        Metres.

    Raises
    ------
    ConfigError
        When the cameras' views overlap too little to place ``n`` boards in ``max_tries``
        draws (the message gives how many were placed).
    """
    outline_B = still_outline_B(board)
    centre_B = outline_B.mean(axis=0)
    corners = (board.corners_B(), *board.edge_pairs())
    K0, _, (w0, h0) = cameras[0]
    poses = []
    for _ in range(max_tries):
        if len(poses) == n:
            break
        z = rng.uniform(*depth_m)
        x_n = (rng.uniform(0.1, 0.9) * w0 - K0[0, 2]) / K0[0, 0]
        y_n = (rng.uniform(0.1, 0.9) * h0 - K0[1, 2]) / K0[1, 1]
        axis = rng.uniform(0.0, 2.0 * np.pi)
        tilt = np.deg2rad(rng.uniform(0.0, max_tilt_deg))
        R = R_from_euler([0.0, 0.0, np.deg2rad(rng.uniform(-20.0, 20.0))]) @ R_from_rvec(
            tilt * np.array([np.cos(axis), np.sin(axis), 0.0]))
        T_C0_B = make_T(R, np.array([x_n * z, y_n * z, z]) - R @ centre_B)
        ok = True
        for (K, dist, size), T in zip(cameras, T_Ci_C0, strict=True):
            T_C_B = T @ T_C0_B
            if not (_in_view(project_in_view(T_C_B, outline_B, K, dist), size, margin_px)
                    and _min_square_px(T_C_B, corners, K, dist) >= min_square_px
                    and (T_C_B[:3, 2] @ T_C_B[:3, 3]) > 0.0):  # the printed side faces it
                ok = False
                break
        if ok:
            poses.append(T_C0_B)
    if len(poses) < n:
        raise ConfigError(
            f"stereo stills: placed {len(poses)} of {n} boards seen whole by all "
            f"{len(cameras)} cameras in {max_tries} draws; the cameras' views overlap too little")
    return np.array(poses)


def render_shared_stills(session_cfgs, T_Ci_C0, n, seed):
    """Stills of ``n`` shared views, one set per camera, with the truth they were made from.

    Parameters
    ----------
    session_cfgs : sequence of dict
        One session block per camera (``config["sessions"][name]`` form: ``synth`` with the
        camera and noise, ``board``, ``markers``); the board must be the same in all.
    T_Ci_C0 : sequence of ndarray, shape (4, 4)
        Each camera's pose from camera 0 (identity first), metres.
    n : int
        Number of shared views.
    seed : int
        Seeds the poses and every camera's image noise.

    Returns
    -------
    stills : list (per camera) of list of (str, ndarray)
        ``(name, gray)``: ``shared_000.png`` ... (the same name in every camera: taken together),
        uint8 (H, W).
    T_C0_B : ndarray, shape (n, 4, 4)
        The true board poses in camera 0, metres.
    """
    specs = [parse_session_config(c) for c in session_cfgs]
    if len({(s.board.nx, s.board.ny, s.board.square_m) for s in specs}) != 1:
        raise ConfigError("stereo stills: every camera's session must have the same board")
    rng = np.random.default_rng(seed)
    cameras = [(s.K, s.dist, s.image_size) for s in specs]
    T_C0_B = shared_view_poses(rng, n, cameras, T_Ci_C0, specs[0].board)
    stills = []
    for c, (spec, T) in enumerate(zip(specs, T_Ci_C0, strict=True)):
        rng_c = np.random.default_rng([seed, c])
        renderer = Renderer(spec, rng_c)
        stills.append([(f"shared_{v:03d}.png", renderer.still(T @ T_v, rng_c))
                       for v, T_v in enumerate(T_C0_B)])
    return stills, T_C0_B
