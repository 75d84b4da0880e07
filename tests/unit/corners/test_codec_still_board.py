"""A still board through a motion-compensated codec errs by a motion PnP takes for a pose change.

The same 2 s of the demo's board (fast preset, its first 1.5 s held nearly still) are written
once as MPEG-4 part 2 (the fast preset's codec: frames coded from the last) and once as MJPEG
(every frame a key frame, the same quantiser). Against the renderer's true corners, on the
frames whose corners move under 0.5 px a frame, the share of the corner error's energy in
PnP's six pose directions (the part a pose absorbs, which the reprojection residual cannot
show) is about what independent noise gives (6 / 2n) through MJPEG, and more than 1.6 times
that through MPEG-4: the reason model (T) has a still-board term for inter-coded video
(``inter_coded``, :data:`cvsflow.uncertainty.features.STILL_SPEED_PX`). The container's key
frames say which video is which (``video_timing``, corners_summary.yaml ``inter_coded``).
"""

from __future__ import annotations

import copy
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.board.model import board_object_points
from cvsflow.corners.extract import summarise_corners
from cvsflow.io.media import iter_video_gray, video_timing
from cvsflow.synth.render import render_session

pytest.importorskip("av")

REPO = Path(__file__).resolve().parents[3]


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """The demo session, 2 s, fast preset, written by each codec: {codec: folder}."""
    with open(REPO / "config" / "config.yaml") as fh:
        base = copy.deepcopy(yaml.safe_load(fh)["sessions"]["demo"])
    base["synth"].update(preset="fast", duration_s=2.0, n_stills=3, seed=23)
    out = {}
    for codec in ("mp4v", "mjpeg"):
        cfg = copy.deepcopy(base)
        cfg["synth"]["codec"] = {"name": codec}
        out[codec] = tmp_path_factory.mktemp(codec)
        render_session(cfg, out[codec])
    return out, base["board"]


def pose_share_still(folder, board):
    """(energy share of the still frames' corner errors in PnP's pose directions, 6 / 2n)."""
    truth = pd.read_parquet(folder / "truth_corners.parquet")
    poses = pd.read_parquet(folder / "truth_frames.parquet").set_index("frame")
    cam = yaml.safe_load((folder / "truth.yaml").read_text())["camera"]
    K, dist = np.array(cam["K"], float), np.array(cam["dist"], float)
    p_B = board_object_points(board)
    by_corner = truth.sort_values(["corner", "frame"])
    step = by_corner.groupby("corner")[["u_px", "v_px"]].diff()
    speed = np.hypot(step["u_px"], step["v_px"]).groupby(by_corner["frame"]).median()
    absorbed = total = 0.0
    n_still = 0
    for f, _, gray in iter_video_gray(folder / "video.mp4"):
        g = truth[truth["frame"] == f].sort_values("corner")
        if f == 0 or not g["in_image"].all() or not speed[f] < 0.5:
            continue
        uv = g[["u_px", "v_px"]].to_numpy()
        square_px = np.median(np.linalg.norm(np.diff(uv[: board["squares_x"] - 1], axis=0), axis=1))
        half = max(2, int(round(square_px / 4)))
        found = cv2.cornerSubPix(gray, np.ascontiguousarray(uv, np.float32).reshape(-1, 1, 2),
                                 (half, half), (-1, -1), (3, 40, 0.001)).reshape(-1, 2)
        err = (found - uv).ravel()
        q = poses.loc[f, ["qx", "qy", "qz", "qw"]].to_numpy(float)
        rvec = cv2.Rodrigues(_R_from_quat(q))[0]
        tvec = poses.loc[f, ["x_m", "y_m", "z_m"]].to_numpy(float)
        _, jac = cv2.projectPoints(p_B.reshape(-1, 1, 3), rvec, tvec, K, dist)
        basis, _ = np.linalg.qr(jac[:, :6])
        absorbed += float(np.sum((basis.T @ err) ** 2))
        total += float(np.sum(err**2))
        n_still += 1
    assert n_still >= 30  # the fast preset's board is held nearly still for its first 1.5 s
    return absorbed / total, 6.0 / (2 * len(p_B))


def _R_from_quat(q):
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(q).as_matrix()


def test_still_board_error_is_pose_like_through_an_inter_codec_only(renders):
    folders, board = renders
    share_mpeg4, iid = pose_share_still(folders["mp4v"], board)
    share_mjpeg, _ = pose_share_still(folders["mjpeg"], board)
    assert share_mjpeg < 1.3 * iid, (share_mjpeg, iid)
    assert share_mpeg4 > 1.6 * iid, (share_mpeg4, iid)


def test_key_frames_tell_an_inter_coded_video(renders):
    folders, _ = renders
    mpeg4, mjpeg = video_timing(folders["mp4v"] / "video.mp4"), video_timing(folders["mjpeg"] / "video.mp4")
    assert mpeg4["codec"] == "mpeg4" and 0 < mpeg4["n_key_frames"] < mpeg4["n_frames"]
    assert mjpeg["codec"] == "mjpeg" and mjpeg["n_key_frames"] == mjpeg["n_frames"]
    corners = pd.DataFrame({"frame": [0], "found": [False], "corner": [-1]})
    assert summarise_corners(corners, mpeg4)["inter_coded"] is True
    summary = summarise_corners(corners, mjpeg)
    assert summary["inter_coded"] is False and summary["key_frame_share"] == 1.0
    assert summary["codec"] == "mjpeg"
