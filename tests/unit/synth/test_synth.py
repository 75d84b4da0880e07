"""Tests of the demo-session renderer (cvsflow.synth) against its own ground truth."""

from __future__ import annotations

import copy
import hashlib
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.calibration.intrinsics import calibrate_camera
from cvsflow.exceptions import ConfigError
from cvsflow.geometry import umeyama
from cvsflow.geometry.transforms import T_from_pose6, euler_from_R, invert_T, rotation_angle, rvec_tvec_from_T
from cvsflow.io import synth_out
from cvsflow.synth.board_image import make_board_texture
from cvsflow.synth.frames import Renderer
from cvsflow.synth.imaging import Board, project_in_view
from cvsflow.synth.markers import true_mounting
from cvsflow.synth.motion import board_poses, make_hand_motion, still_poses
from cvsflow.synth.render import render_session, render_stills
from cvsflow.synth.session import make_rig, still_outline_B, vicon_recording, video_truth
from cvsflow.synth.spec import IMAGE_SIZE, parse_session_config, random_streams

REPO = Path(__file__).resolve().parents[3]


def demo_cfg(duration_s=3.0, n_stills=3, seed=7):
    """The demo session's config from config/config.yaml, shortened for tests."""
    with open(REPO / "config" / "config.yaml") as fh:
        cfg = copy.deepcopy(yaml.safe_load(fh)["sessions"]["demo"])
    cfg["synth"].update(duration_s=duration_s, n_stills=n_stills, seed=seed)
    return cfg


@pytest.fixture(scope="module")
def spec():
    return parse_session_config(demo_cfg())


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """A 3 s session rendered twice with one seed and once with another."""
    base = tmp_path_factory.mktemp("synth")
    out = {}
    for key, seed in (("a", 7), ("b", 7), ("c", 8)):
        out[key] = base / key / "demo"
        out[key + "_summary"] = render_session(demo_cfg(seed=seed), out[key])
    return out


def _file_digests(folder):
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(Path(folder).rglob("*"))
        if p.is_file()
    }


def test_session_has_contract_files(rendered):
    """render_session writes exactly the data/{session}/ files of docs/contracts.md."""
    folder = rendered["a"]
    names = sorted(p.name for p in folder.iterdir())
    assert names == sorted(synth_out.SESSION_FILES)
    stills = sorted((folder / "calib").glob("*.png"))
    assert len(stills) == 3
    assert cv2.imread(str(stills[0]), cv2.IMREAD_GRAYSCALE).shape == (480, 640)
    cap = cv2.VideoCapture(str(folder / "video.mp4"))
    assert cap.get(cv2.CAP_PROP_FPS) == pytest.approx(30.0)
    n = 0
    while cap.read()[0]:
        n += 1
    assert n == 90
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    for key in ("camera", "T_Cm_C", "T_Bm_B", "T_W_Cm", "dt_offset_s", "fps", "vicon_rate_hz",
                "markers_Cm_m", "markers_Bm_m", "board", "n_frames"):
        assert key in truth
    assert truth["n_frames"] == 90
    frames = pd.read_parquet(folder / "truth_frames.parquet")
    assert list(frames.columns[:14]) == [
        "frame", "t_s", "x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad",
        "qx", "qy", "qz", "qw", "in_view", "blur_px",
    ]
    corners = pd.read_parquet(folder / "truth_corners.parquet")
    assert list(corners.columns) == ["frame", "corner", "u_px", "v_px"]
    assert len(corners) == 90 * 20
    assert not any(p.name.startswith(".") for p in folder.parent.iterdir())


def test_same_seed_same_files_other_seed_different(rendered):
    """Rendering is deterministic from synth.seed; another seed changes every data file."""
    a, b, c = (_file_digests(rendered[k]) for k in "abc")
    assert a == b
    for name in ("video.mp4", "vicon.csv", "truth.yaml", "calib/still_00.png"):
        assert a[name] != c[name]


def test_vicon_csv_is_nexus_format(rendered):
    """vicon.csv has the Nexus Trajectories header, CRLF line ends and empty cells for gaps."""
    raw = (rendered["a"] / "vicon.csv").read_bytes()
    assert raw.count(b"\r\n") == raw.count(b"\n")
    lines = raw.decode().split("\r\n")
    assert lines[0].split(",")[0] == "Trajectories"
    assert lines[1].split(",")[0] == "300"
    names = [c for c in lines[2].split(",") if c]
    assert names == ["camera:C1", "camera:C2", "camera:C3", "camera:C4",
                     "board:B1", "board:B2", "board:B3", "board:B4"]
    assert lines[2].split(",")[2::3] == names
    assert lines[3].split(",") == ["Frame", "Sub Frame"] + ["X", "Y", "Z"] * 8
    assert lines[4].split(",") == ["", ""] + ["mm"] * 24
    first = lines[5].split(",")
    assert first[:2] == ["1", "0"] and len(first) == 26
    rows = [ln.split(",") for ln in lines[5:] if ln]
    truth = yaml.safe_load((rendered["a"] / "truth.yaml").read_text())
    n_expected = int(np.ceil((3.0 + 1.5 + truth["dt_offset_s"]) * 300))
    assert len(rows) == n_expected
    assert [int(r[0]) for r in rows[:3]] == [1, 2, 3]
    # Nexus leaves occluded samples as empty cells, three at a time
    empty = [i for r in rows for i, c in enumerate(r) if c == ""]
    assert len(empty) > 0 and len(empty) % 3 == 0
    # camera markers are still: C1 within a few mm of its true place (mm in the file)
    c1 = np.array([[float(v) for v in r[2:5]] for r in rows if r[2] != ""])
    assert np.std(c1, axis=0).max() < 1.0


def test_rendered_corners_match_truth(spec):
    """findChessboardCorners + cornerSubPix on rendered stills land within 0.3 px of truth."""
    rng = np.random.default_rng(3)
    renderer = Renderer(spec, np.random.default_rng(4))
    corners_B = spec.board.corners_B()
    poses = still_poses(rng, 6, spec.K, spec.dist, IMAGE_SIZE, still_outline_B(spec.board))
    errors = []
    for T_C_B in poses:
        image = renderer.still(T_C_B, rng)
        found, c = cv2.findChessboardCorners(image, (spec.board.nx, spec.board.ny))
        assert found
        c = cv2.cornerSubPix(
            image, c, (5, 5), (-1, -1),
            (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 50, 1e-4),
        )[:, 0]
        truth = project_in_view(T_C_B, corners_B, spec.K, spec.dist)
        # OpenCV may number the grid from either end; the nearer order is the match
        err = min(np.linalg.norm(c - truth, axis=1).max(),
                  np.linalg.norm(c[::-1] - truth, axis=1).max())
        errors.append(err)
    assert max(errors) < 0.3, errors


def test_project_in_view_matches_opencv(spec):
    """project_in_view reproduces cv2.projectPoints (5-term distortion) to 1e-6 px."""
    rng = np.random.default_rng(5)
    corners_B = spec.board.corners_B()
    for _ in range(5):
        T_C_B = T_from_pose6(np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(1, 3),
                                   rng.uniform(-0.6, 0.6, 3)])
        rvec, tvec = rvec_tvec_from_T(T_C_B)
        ref, _ = cv2.projectPoints(corners_B, rvec, tvec, spec.K, spec.dist)
        np.testing.assert_allclose(
            project_in_view(T_C_B, corners_B, spec.K, spec.dist), ref[:, 0], atol=1e-6
        )


def test_black_square_outside_corner_zero():
    """The square diagonally outside inner corner 0 is black, the opposite outer one white."""
    board = Board(6, 5, 0.09)
    tex = make_board_texture(board)
    level = tex.levels[0]

    def reflectance_at(x_m, y_m):
        c = int((x_m - tex.x0_m) * tex.ppm[0])
        r = int((y_m - tex.y0_m) * tex.ppm[0])
        return level[r, c, 0] / level[r, c, 1]

    s = 0.09
    assert reflectance_at(-s / 2, -s / 2) < 0.1
    assert reflectance_at(4 * s + s / 2, 3 * s + s / 2) > 0.8
    assert reflectance_at(s / 2, -s / 2) > 0.8


def test_true_mounting_is_least_squares_fit():
    """A rigid fit of the layout to the real markers in the true body frame is the identity."""
    rng = np.random.default_rng(11)
    layout = np.array([[0, 0, 0], [0.76, 0, 0], [0, 0.52, 0], [0.58, 0.5, 0]], float)
    T_design = T_from_pose6([0.2, 0.395, -0.004, np.pi, 0, 0])
    err = rng.normal(0, 0.003, layout.shape)
    T_Bm_B, markers = true_mounting(T_design, layout, err)
    T_fit = umeyama(layout, markers)[0]
    np.testing.assert_allclose(T_fit, np.eye(4), atol=1e-12)
    # the correction is small (placement errors of 3 mm) but not zero
    assert 1e-5 < np.linalg.norm(T_Bm_B[:3, 3] - T_design[:3, 3]) < 0.01
    np.testing.assert_allclose(np.linalg.norm(markers - layout, axis=1).mean(), 0.004, atol=0.003)


def test_vicon_markers_reconstruct_board_pose(spec):
    """Noise-free markers give T_W_Bm = T_W_Cm T_Cm_C T_C_B(t_vicon - dt) inv(T_Bm_B), sub-mm."""
    from dataclasses import replace

    clean = replace(spec, marker_noise_sigma_m=0.0, dropout_rate_hz=0.0)
    rngs = random_streams(7)
    rig = make_rig(clean, rngs["mounting"])
    motion = make_hand_motion(rngs["motion"], clean.K, IMAGE_SIZE, clean.board.center_B())
    df, _, n_drop = vicon_recording(clean, rig, motion, rngs["vicon"])
    assert n_drop == 0
    names = list(clean.board_names)
    idx = np.arange(0, len(df), 97)
    xyz = np.stack([df[[f"{n}_{a}_m" for a in "xyz"]].to_numpy()[idx] for n in names], axis=1)
    t_video = df["t_s"].to_numpy()[idx] - rig.dt_offset_s
    T_expected = rig.T_W_Cm @ rig.T_Cm_C @ board_poses(motion, t_video) @ invert_T(rig.T_Bm_B)
    for k in range(len(idx)):
        T_fit = umeyama(clean.board_layout_m, xyz[k])[0]
        assert np.linalg.norm(T_fit[:3, 3] - T_expected[k, :3, 3]) < 1e-4
        assert rotation_angle(T_fit[:3, :3].T @ T_expected[k, :3, :3]) < 1e-4
    cam = np.stack([df[[f"{n}_{a}_m" for a in "xyz"]].to_numpy()[0] for n in clean.camera_names])
    np.testing.assert_allclose(umeyama(clean.camera_layout_m, cam)[0], rig.T_W_Cm, atol=1e-4)
    # the offset is not a whole number of Vicon samples
    frac = (rig.dt_offset_s * 300) % 1.0
    assert 0.1 < frac < 0.9


def test_noisy_vicon_has_noise_and_dropouts(spec):
    """Marker noise has the configured sigma and dropouts are short runs of empty samples."""
    rngs = random_streams(7)
    rig = make_rig(spec, rngs["mounting"])
    motion = make_hand_motion(rngs["motion"], spec.K, IMAGE_SIZE, spec.board.center_B())
    df, _, n_drop = vicon_recording(spec, rig, motion, rngs["vicon"])
    c1 = df[["camera:C1_x_m", "camera:C1_y_m", "camera:C1_z_m"]].to_numpy()
    sd = np.nanstd(c1, axis=0)
    np.testing.assert_allclose(sd, spec.marker_noise_sigma_m, rtol=0.2)
    gaps = df[[c for c in df.columns if c.endswith("_x_m")]].isna().to_numpy()
    assert gaps.any() and n_drop > 0
    # no run longer than dropout_max_s (+1 sample where two dropouts touch at most doubles it)
    run, longest = np.zeros(gaps.shape[1], int), 0
    for row in gaps:
        run = np.where(row, run + 1, 0)
        longest = max(longest, run.max())
    assert longest <= 2 * round(spec.dropout_max_s * 300)


def test_sync_gesture_at_start(spec):
    """The board is still, then tilts forward >15 deg about its x axis within ~3 s, and back."""
    rngs = random_streams(7)
    motion = make_hand_motion(rngs["motion"], spec.K, IMAGE_SIZE, spec.board.center_B())
    rig = make_rig(spec, rngs["mounting"])
    t_s = np.arange(0, 3.0, 1 / 30)
    T_C_B = board_poses(motion, t_s)
    roll = np.rad2deg(euler_from_R(T_C_B[:, :3, :3])[:, 0])
    assert np.ptp(roll[t_s < 1.4]) < 1.0
    assert np.ptp(roll) > 15.0
    center_C = T_C_B[:, :3, :3] @ spec.board.center_B() + T_C_B[:, :3, 3]
    assert np.ptp(center_C[t_s < 2.6], axis=0).max() < 0.03
    # the gesture is filmed: the board is wholly in view while it is made
    assert video_truth(spec, motion, np.full(90, 0.014)).in_view[: int(2.6 * 30)].all()
    # In W the gesture turns the board body about W's horizontal axis across the view
    # (a pitch for a W-aligned body), whatever the marker body's own axes.
    T_W_Bm = rig.T_W_Cm @ rig.T_Cm_C @ T_C_B @ invert_T(rig.T_Bm_B)
    dR_W = T_W_Bm[:, :3, :3] @ T_W_Bm[0, :3, :3].T
    k = int(np.argmax(rotation_angle(dR_W)))
    rvec_W = rvec_tvec_from_T(np.r_[np.c_[dR_W[k], np.zeros(3)], [[0, 0, 0, 1]]])[0]
    assert np.rad2deg(np.linalg.norm(rvec_W)) > 15.0
    view_W = rig.T_W_Cm[:3, :3] @ rig.T_Cm_C[:3, 2]
    across_W = np.cross([0, 0, 1.0], view_W)
    cos_axis = abs(rvec_W @ across_W) / np.linalg.norm(rvec_W) / np.linalg.norm(across_W)
    assert cos_axis > 0.95


def test_board_in_view_most_but_not_all_frames():
    """Over a 90 s session the board is wholly in view in most frames, not in all; depth 1-4 m."""
    spec90 = parse_session_config(demo_cfg(duration_s=90.0))
    rngs = random_streams(spec90.seed)
    motion = make_hand_motion(rngs["motion"], spec90.K, IMAGE_SIZE, spec90.board.center_B())
    truth = video_truth(spec90, motion, np.full(2700, 0.014))
    assert 0.6 < truth.in_view.mean() < 0.97
    z = truth.T_C_B[:, 2, 3]
    assert z.min() > 0.85 and z.max() < 4.3 and np.ptp(z) > 2.0
    rpy = np.rad2deg(euler_from_R(truth.T_C_B[:, :3, :3]))
    assert np.all(np.abs(rpy).max(axis=0) > 30.0)
    assert (truth.blur_px > 5.0).any()


def test_still_poses_in_view_and_varied(spec):
    """Calibration stills show the whole printed board at 0.6-2.5 m, tilted up to ~50 degrees
    about the board's x axis, its y axis and both, with squares of at least 20 px."""
    rng = np.random.default_rng(2)
    outline = still_outline_B(spec.board)
    poses = still_poses(rng, 15, spec.K, spec.dist, IMAGE_SIZE, outline, board=spec.board)
    assert len(poses) == 15
    uv = project_in_view(poses, outline, spec.K, spec.dist)
    assert np.all((uv >= 10) & (uv <= [629, 469]))
    assert poses[:, 2, 3].min() > 0.6 and poses[:, 2, 3].max() < 2.5
    assert np.ptp(poses[:, 2, 3]) > 0.8
    tilt = np.rad2deg(np.arccos(poses[:, 2, 2]))
    assert tilt.max() > 40.0 and tilt.max() <= 55.0 and tilt.min() > 5.0
    # strong tilts about each board axis: the board normal leans along board y, then x
    normal_B = np.einsum("nji,j->ni", poses[:, :3, :3], [0.0, 0.0, 1.0])  # C's z axis in B
    strong = tilt > 38.0
    lean = np.rad2deg(np.arctan2(np.abs(normal_B[strong, 1]), np.abs(normal_B[strong, 0])))
    assert lean.max() > 75.0 and lean.min() < 15.0
    grid = project_in_view(poses, spec.board.corners_B(), spec.K, spec.dist).reshape(15, 4, 5, 2)
    sides = np.r_[np.linalg.norm(np.diff(grid, axis=2), axis=-1).ravel(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=-1).ravel()]
    assert sides.min() >= 20.0
    # deterministic for a given generator state
    again = still_poses(np.random.default_rng(2), 15, spec.K, spec.dist, IMAGE_SIZE, outline,
                        board=spec.board)
    np.testing.assert_array_equal(poses, again)


def test_still_poses_come_nearer_for_a_wide_lens_and_small_squares():
    """A wide webcam (f 518 px, k1 -0.30) and 5 cm squares: at the nominal 1.5-2.1 m a square
    spans ~13 px, below the 20 px refinement floor; every still is still placed, nearer."""
    K = np.array([[520.0, 0.0, 318.0], [0.0, 518.0, 236.0], [0.0, 0.0, 1.0]])
    dist = np.array([-0.30, 0.11, 0.0004, 0.0011, -0.02])
    board = Board(squares_x=9, squares_y=7, square_m=0.05)
    outline = still_outline_B(board)
    poses = still_poses(np.random.default_rng(31), 15, K, dist, (640, 480), outline, board=board)
    assert len(poses) == 15
    grid = project_in_view(poses, board.corners_B(), K, dist).reshape(15, board.ny, board.nx, 2)
    sides = np.r_[np.linalg.norm(np.diff(grid, axis=2), axis=-1).ravel(),
                  np.linalg.norm(np.diff(grid, axis=1), axis=-1).ravel()]
    assert sides.min() >= 20.0
    uv = project_in_view(poses, outline, K, dist)
    assert np.all((uv >= 10) & (uv <= [629, 469]))
    assert poses[:, 2, 3].max() < 1.3 and np.ptp(poses[:, 2, 3]) > 0.3


@pytest.mark.parametrize("seed", [7, 11, 23])
def test_still_corners_cover_every_image_region(spec, seed):
    """The session's 15 stills put inner corners in every cell of a 3x3 grid of the image,
    and near all four image corners (within 110 px of both borders; the old random poses left
    up to 180 px)."""
    rng = random_streams(seed)["stills"]
    poses = still_poses(rng, 15, spec.K, spec.dist, IMAGE_SIZE, still_outline_B(spec.board),
                        board=spec.board)
    uv = project_in_view(poses, spec.board.corners_B(), spec.K, spec.dist).reshape(-1, 2)
    width, height = IMAGE_SIZE
    col = np.clip((uv[:, 0] * 3 // width).astype(int), 0, 2)
    row = np.clip((uv[:, 1] * 3 // height).astype(int), 0, 2)
    counts = np.zeros((3, 3), int)
    np.add.at(counts, (row, col), 1)
    assert np.all(counts > 0), counts
    for cu in (0, width - 1):
        for cv in (0, height - 1):
            near = (np.abs(uv[:, 0] - cu) < 110) & (np.abs(uv[:, 1] - cv) < 110)
            assert near.any(), (cu, cv)


def test_render_stills_are_the_session_stills(rendered):
    """render_stills gives the very pixels and poses render_session writes to calib/."""
    stills = render_stills(demo_cfg(seed=7))
    truth = yaml.safe_load((rendered["a"] / "truth.yaml").read_text())
    assert [name for name, _, _ in stills] == sorted(truth["stills"])
    for name, image, T_C_B in stills:
        written = cv2.imread(str(rendered["a"] / "calib" / name), cv2.IMREAD_GRAYSCALE)
        np.testing.assert_array_equal(image, written)
        np.testing.assert_allclose(T_C_B, truth["stills"][name]["T_C_B"], atol=1e-9)


@pytest.mark.parametrize("seed", [7, 11, 23])
def test_calibration_on_rendered_stills_recovers_truth(seed):
    """calibrate_camera on the session's 15 rendered stills finds the true camera: principal
    point within 1 px, focal lengths within 0.2 %, distortion within 1.5 px at the image
    corners. (At the stills' corner noise, ~0.05 px, the principal point's standard error is
    ~0.6 px, so 1 px is a bound for these seeds, not for every seed.)"""
    cfg = demo_cfg(n_stills=15, seed=seed)
    spec = parse_session_config(cfg)
    stills = render_stills(cfg)
    camera, _ = calibrate_camera([(name, image) for name, image, _ in stills], cfg["board"])
    assert camera["n_used"] == 15
    K = np.array(camera["K"])
    assert abs(K[0, 2] - spec.K[0, 2]) < 1.0
    assert abs(K[1, 2] - spec.K[1, 2]) < 1.0
    assert abs(K[0, 0] / spec.K[0, 0] - 1.0) < 0.002
    assert abs(K[1, 1] / spec.K[1, 1] - 1.0) < 0.002
    # distortion alone, at the image corners: true rays through the corner pixels, projected
    # with the true K and the calibrated distortion, land within 1.5 px of those pixels
    corners_px = np.array([[0, 0], [639, 0], [0, 479], [639, 479]], float)
    rays = cv2.undistortPointsIter(
        corners_px.reshape(-1, 1, 2), spec.K, spec.dist, None, None,
        (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12),
    ).reshape(-1, 2)
    back, _ = cv2.projectPoints(np.c_[rays, np.ones(4)], np.zeros(3), np.zeros(3), spec.K,
                                np.array(camera["dist"]))
    assert np.linalg.norm(back[:, 0] - corners_px, axis=1).max() < 1.5


def test_missing_config_key_is_named():
    """A missing synth key raises ConfigError naming the key."""
    cfg = demo_cfg()
    del cfg["synth"]["T_Bm_B_pose6"]
    with pytest.raises(ConfigError, match="T_Bm_B_pose6"):
        parse_session_config(cfg)


def test_progress_counts_every_rendered_frame(tmp_path):
    """render_session calls progress(n) after each video frame; session_frame_count is the total."""
    from cvsflow.synth.render import session_frame_count

    cfg = demo_cfg(duration_s=0.5, n_stills=1)
    done = []
    summary = render_session(cfg, tmp_path / "demo", progress=done.append)
    assert session_frame_count(cfg) == summary["n_frames"] == 15
    assert done == list(range(1, 16))


def test_failure_leaves_no_output(tmp_path, monkeypatch):
    """A failure while rendering leaves neither the session folder nor temporary folders."""

    def broken(self, grey):
        raise RuntimeError("disk full")

    monkeypatch.setattr(synth_out.VideoSink, "write", broken)
    with pytest.raises(RuntimeError):
        render_session(demo_cfg(duration_s=0.5, n_stills=1), tmp_path / "demo")
    assert list(tmp_path.iterdir()) == []


def test_foreign_files_are_not_replaced(tmp_path):
    """An out_dir holding files the renderer did not write is refused and left untouched."""
    out = tmp_path / "demo"
    out.mkdir()
    (out / "my_recording.mp4").write_bytes(b"precious")
    with pytest.raises(ConfigError, match="my_recording.mp4"):
        render_session(demo_cfg(duration_s=0.5, n_stills=1), out)
    assert (out / "my_recording.mp4").read_bytes() == b"precious"


def test_files_agree_vicon_and_video_truth(rendered):
    """vicon.csv read back, fitted and shifted by dt_offset_s matches truth_frames' T_C_B (2 mm)."""
    from cvsflow.geometry.transforms import R_from_quat, make_T
    from cvsflow.io.mocap.vicon import read_nexus_csv

    folder = rendered["a"]
    truth = yaml.safe_load((folder / "truth.yaml").read_text())
    frames = pd.read_parquet(folder / "truth_frames.parquet")
    markers = read_nexus_csv(folder / "vicon.csv")
    rate = truth["vicon_rate_hz"]
    T_W_Cm, T_Cm_C, T_Bm_B = (np.array(truth[k]) for k in ("T_W_Cm", "T_Cm_C", "T_Bm_B"))
    names = list(truth["markers_Bm_m"])
    layout = np.array(list(truth["markers_Bm_m"].values()))
    checked = 0
    for _, row in frames.iloc[::7].iterrows():
        j = (row["t_s"] + truth["dt_offset_s"]) * rate  # fractional Vicon sample index
        j0 = int(np.floor(j))
        fits = []
        for jj in (j0, j0 + 1):
            xyz = np.stack([markers[[f"{n}_{a}_m" for a in "xyz"]].to_numpy()[jj] for n in names])
            if np.isnan(xyz).any():
                break
            fits.append(umeyama(layout, xyz)[0])
        if len(fits) < 2:
            continue
        w = j - j0
        T_W_Bm = fits[0].copy()
        T_W_Bm[:3, 3] = (1 - w) * fits[0][:3, 3] + w * fits[1][:3, 3]
        T_C_B_vicon = invert_T(T_W_Cm @ T_Cm_C) @ T_W_Bm @ T_Bm_B
        q = row[["qx", "qy", "qz", "qw"]].to_numpy(float)
        T_C_B = make_T(R_from_quat(q), row[["x_m", "y_m", "z_m"]].to_numpy(float))
        assert np.linalg.norm(T_C_B_vicon[:3, 3] - T_C_B[:3, 3]) < 0.002
        assert np.rad2deg(rotation_angle(T_C_B_vicon[:3, :3].T @ T_C_B[:3, :3])) < 0.2
        checked += 1
    assert checked > 8


# --------------------------------------------------------------------------- moving camera


def _moving_spec(spec, **camera_motion):
    from dataclasses import replace

    from cvsflow.synth.spec import parse_camera_motion

    return replace(spec, marker_noise_sigma_m=0.0, dropout_rate_hz=0.0,
                   camera_motion=parse_camera_motion(camera_motion))  # fmt: skip


def _fitted_bodies(df, spec):
    """Rigid fits T_W_Cm, T_W_Bm (N, 4, 4) of the noise-free marker table, every 97th sample."""
    idx = np.arange(0, len(df), 97)
    out = []
    for names, layout in ((spec.camera_names, spec.camera_layout_m),
                          (spec.board_names, spec.board_layout_m)):  # fmt: skip
        xyz = np.stack([df[[f"{n}_{a}_m" for a in "xyz"]].to_numpy()[idx] for n in names], axis=1)
        out.append(np.stack([umeyama(layout, xyz[k])[0] for k in range(len(idx))]))
    return df["t_s"].to_numpy()[idx], out[0], out[1]


@pytest.mark.parametrize("kind", ["handheld", "orbit"])
def test_moving_camera_vicon_gives_the_same_relative_motion(spec, kind):
    """A moving camera changes the Vicon, not the video: the noise-free markers of both bodies
    give inv(T_W_Cm T_Cm_C) T_W_Bm T_Bm_B = board_poses (the images' T_C_B) to 0.1 mm and
    0.1 mrad, the camera body follows camera_track and travels; handheld: the board body
    stands still; orbit: the lens keeps its horizontal distance to the pivot."""
    from cvsflow.synth.session import camera_track

    moving = _moving_spec(spec, type=kind)
    rngs = random_streams(7)
    rig = make_rig(moving, rngs["mounting"])
    motion = make_hand_motion(rngs["motion"], moving.K, IMAGE_SIZE, moving.board.center_B())
    df, _, _ = vicon_recording(moving, rig, motion, rngs["vicon"])
    t_vicon, T_W_Cm, T_W_Bm = _fitted_bodies(df, moving)
    t_video = t_vicon - rig.dt_offset_s
    T_C_B = invert_T(T_W_Cm @ rig.T_Cm_C) @ T_W_Bm @ rig.T_Bm_B
    expected = board_poses(motion, t_video)
    assert np.abs(T_C_B[:, :3, 3] - expected[:, :3, 3]).max() < 1e-4
    assert rotation_angle(np.swapaxes(T_C_B[:, :3, :3], 1, 2) @ expected[:, :3, :3]).max() < 1e-4
    track = camera_track(moving, rig, motion, t_video)
    assert np.abs(T_W_Cm[:, :3, 3] - track[:, :3, 3]).max() < 1e-4
    np.testing.assert_allclose(camera_track(moving, rig, motion, np.zeros(1))[0], rig.T_W_Cm,
                               atol=1e-12)  # fmt: skip
    assert np.ptp(T_W_Cm[:, :3, 3], axis=0).max() > 0.1
    if kind == "handheld":
        assert np.ptp(T_W_Bm[:, :3, 3], axis=0).max() < 1e-4
    else:
        T_W_C = track @ rig.T_Cm_C
        T_W_C0 = rig.T_W_Cm @ rig.T_Cm_C
        pivot = T_W_C0[:3, 3] + moving.camera_motion.radius_m * T_W_C0[:3, 2]
        d_xy = np.linalg.norm((T_W_C[:, :3, 3] - pivot)[:, :2], axis=1)
        np.testing.assert_allclose(d_xy, np.linalg.norm((T_W_C0[:3, 3] - pivot)[:2]), atol=1e-9)


def test_moving_camera_truth_tables_and_config(spec):
    """truth_frames gains T_W_C per frame (cam_x_m .. cam_qw) and truth.yaml the motion only
    for a moving camera; a static one keeps the demo's columns and keys; bad config named."""
    from cvsflow.synth.session import camera_track, truth_document, truth_tables
    from cvsflow.synth.spec import parse_camera_motion

    rngs = random_streams(7)
    rig = make_rig(spec, rngs["mounting"])
    motion = make_hand_motion(rngs["motion"], spec.K, IMAGE_SIZE, spec.board.center_B())
    truth = video_truth(spec, motion, np.full(90, 0.014))
    static_frames, _ = truth_tables(spec, truth)
    assert not any(c.startswith("cam_") for c in static_frames.columns)
    assert "camera_motion" not in truth_document(spec, rig, 90, {})
    moving = _moving_spec(spec, type="handheld")
    T_W_C = camera_track(moving, rig, motion, truth.t_s) @ rig.T_Cm_C
    frames, _ = truth_tables(moving, truth, T_W_C)
    assert list(frames.columns[: len(static_frames.columns)]) == list(static_frames.columns)
    np.testing.assert_allclose(frames[["cam_x_m", "cam_y_m", "cam_z_m"]], T_W_C[:, :3, 3])
    assert truth_document(moving, rig, 90, {})["camera_motion"]["type"] == "handheld"
    with pytest.raises(ConfigError, match="camera_motion.type"):
        parse_camera_motion({"type": "drone"})
    with pytest.raises(ConfigError, match="unknown keys"):
        parse_camera_motion({"type": "orbit", "radius": 2.0})
    with pytest.raises(ConfigError, match="period_s"):
        parse_camera_motion({"type": "orbit", "period_s": 0.0})
