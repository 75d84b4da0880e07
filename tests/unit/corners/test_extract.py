"""Tests of cvsflow.corners.extract: the corners table (``extract_corners``, its tracking path), and the
chunked and parallel extraction, against rendered ground truth."""

from __future__ import annotations

import functools
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow.board.model import CORNER_COLUMNS
from cvsflow.corners.detect import detect_corners, quick_detect_corners
from cvsflow.corners.extract import (
    chunk_ranges,
    extract_corners,
    extract_corners_parallel,
    extract_corners_range,
    merge_corner_chunks,
)
from cvsflow.corners.track import track_corners
from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf
from cvsflow.io.media import iter_video_gray
from tests.helpers.board_images import board_centre_pose, random_board_poses, render_board

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}  # the demo board, 5x4 inner corners
W, H = 640, 480
K = np.array([[700.0, 0.0, (W - 1) / 2], [0.0, 700.0, (H - 1) / 2], [0.0, 0.0, 1.0]])
N_FRAMES = 96
K_CENTRED = K  # principal point at the pixel centre
BOARD_10x7 = {"squares_x": 11, "squares_y": 8, "square_m": 0.055}
WIDE_DIST = [-0.30, 0.11, 0.0, 0.0, -0.02]  # a wide lens, k1 ~ -0.3


def _render(T_C_B, seed, pps=24, margin=1, noise_sigma=2.0):
    """Grey image of the demo board and its true corners (N, 2) in board order."""
    return render_board(T_C_B, K, BOARD, pps=pps, margin=margin, noise_sigma=noise_sigma, seed=seed)


def _pose(frame):
    """Board pose at a frame of the test sequence: it swings right until partly out of view
    (frames 24 to 29), then left (65 to 72), turning and tilting as it goes."""
    a = 2 * np.pi * frame / N_FRAMES
    centre = np.array([0.45 * np.sin(a), 0.08 * np.sin(2 * a), 1.5 + 0.2 * np.cos(a)])
    rpy = np.radians([15 * np.sin(a), 20 * np.cos(a), 30 * np.sin(0.5 * a)])
    R = tf.R_from_euler(rpy)
    c_B = np.array([2 * BOARD["square_m"], 1.5 * BOARD["square_m"], 0.0])
    return tf.make_T(R, centre - R @ c_B)


def sequence_source(start, stop=None):
    """Frame source of the test sequence: (frame, t_s, gray) for frames [start, stop)."""
    for f in range(start, N_FRAMES if stop is None else min(stop, N_FRAMES)):
        yield f, f / 30.0, _render(_pose(f), seed=f)[0]


@pytest.fixture(scope="module")
def sequence():
    """Frames, true corners and in-view flags (all corners >= 4 px inside) of the sequence."""
    frames, truth = [], []
    for f in range(N_FRAMES):
        gray, uv = _render(_pose(f), seed=f)
        frames.append((f, f / 30.0, gray))
        truth.append(uv)
    truth = np.array(truth)
    in_view = np.all((truth >= 4) & (truth <= np.array([W - 5, H - 5])), axis=(1, 2))
    return frames, truth, in_view


def _found(corners):
    return corners.groupby("frame")["found"].first().to_numpy()


def test_sequence_leaves_and_reenters_the_view(sequence):
    """The test sequence does what the tracking tests need: whole board, then partly out of
    view for several frames, then whole again."""
    _, _, in_view = sequence
    assert in_view[:20].all() and in_view[-20:].all()
    assert (~in_view).sum() >= 8


def test_tracking_against_truth_and_full_detection(sequence):
    """With tracking, the board is found in every frame where full detection finds it (and
    maybe more); where the board is partly out of view only corners inside the image are kept
    (keep_partial), with their true indices; corner k within 0.3 px of true corner k; most
    frames are tracked, and frames partly out of view are followed, not detected; without
    keep_partial those frames are not found."""
    frames, truth, in_view = sequence
    full = extract_corners(iter(frames), BOARD, track=False, restart_every=None)
    fast = extract_corners(iter(frames), BOARD)
    found_full, found_fast = _found(full), _found(fast)
    assert found_full[in_view].mean() > 0.9
    assert (found_fast >= found_full).all()
    assert found_fast[~in_view].any()
    uv = fast[fast["found"]]
    true_uv = truth[uv["frame"], uv["corner"]]
    assert ((true_uv >= 0) & (true_uv <= np.array([W - 1, H - 1]))).all()
    whole_only = extract_corners(iter(frames), BOARD, keep_partial=False, log_every=0)
    assert not _found(whole_only)[~in_view].any()
    err = np.linalg.norm(uv[["u_px", "v_px"]].to_numpy() - truth[uv["frame"], uv["corner"]], axis=1)
    assert err.max() < 0.3
    methods = fast.attrs["order_methods"]
    assert methods.get("tracked", 0) >= 0.7 * N_FRAMES
    assert methods.get("out_of_view", 0) + methods.get("out_of_view_back", 0) >= 5


def test_chunks_equal_single_pass(sequence):
    """Chunks cut at multiples of restart_every, joined, give exactly the single-pass table
    (also when a chunk starts while the board is partly out of view)."""
    frames, _, in_view = sequence
    single = extract_corners(iter(frames), BOARD, restart_every=8)
    ranges = chunk_ranges(N_FRAMES, 4, restart_every=8)
    assert [r[0] for r in ranges] == [0, 24, 48, 72] and ranges[-1][1] is None
    assert not in_view[24] and not in_view[72]  # chunks starting with the board partly out
    chunks = [
        extract_corners_range(sequence_source, a, b, BOARD, restart_every=8) for a, b in ranges
    ]
    merged = merge_corner_chunks(chunks[::-1])
    pd.testing.assert_frame_equal(merged, single)
    assert merged.attrs == single.attrs


def test_parallel_equals_single_pass():
    """Two worker processes give the single-pass table."""
    single = extract_corners(sequence_source(0), BOARD, restart_every=48)
    parallel = extract_corners_parallel(
        sequence_source, N_FRAMES, BOARD, n_workers=2, restart_every=48
    )
    pd.testing.assert_frame_equal(parallel, single)


def test_chunk_must_start_at_a_restart():
    """A chunk starting between restarts would differ from a single pass: refused."""
    with pytest.raises(ValueError, match="multiple of restart_every"):
        extract_corners_range(sequence_source, 10, 20, BOARD, restart_every=8)


def test_merge_refuses_a_gap_between_chunks(sequence):
    """Chunks leaving frames out are an InputError naming the frames."""
    frames, _, _ = sequence
    a = extract_corners(iter(frames[:8]), BOARD)
    b = extract_corners(iter(frames[10:16]), BOARD)
    with pytest.raises(InputError, match="ending at frame 7.*starting at frame 10"):
        merge_corner_chunks([a, b])


@pytest.mark.parametrize("shift", [1, 2])
def test_tracking_refuses_a_grid_slipped_by_squares(sequence, shift):
    """Previous corners slipped by one or two squares along the board's x (a grid whose
    geometry is right but whose corner k is the wrong physical corner) are not accepted."""
    frames, truth, _ = sequence
    f = 5
    slipped = truth[f].reshape(4, 5, 2).copy()
    step = slipped[:, 1:] - slipped[:, :-1]
    for _ in range(shift):
        slipped[:, :-1] = slipped[:, 1:]
        slipped[:, -1] = slipped[:, -2] + step[:, -1]
    corners, method = track_corners(frames[f - 1][2], frames[f][2], slipped.reshape(-1, 2), BOARD)
    assert method == "lost" and corners is None
    corners, method = track_corners(frames[f - 1][2], frames[f][2], truth[f - 1], BOARD)
    assert method == "tracked"
    assert np.abs(corners - truth[f]).max() < 0.3


def test_quick_detection_matches_full_detection(sequence):
    """The half-size detector, refined at full size, gives the full detector's corners (same
    order, within 0.05 px) where it finds the board."""
    frames, truth, _ = sequence
    n = 0
    for f in range(0, 20, 4):
        gray = frames[f][2]
        quick, method = quick_detect_corners(gray, BOARD)
        full, _ = detect_corners(gray, BOARD)
        if quick is None:
            continue
        n += 1
        assert method == "quick"
        assert np.abs(quick - full).max() < 0.05
        assert np.abs(quick - truth[f]).max() < 0.3
    assert n >= 4


def test_video_range_reads_the_frames_of_a_full_read(tmp_path, sequence):
    """iter_video_gray(path, start, stop) yields the same frames and times as reading the
    whole video, from frames inside and at the end of the file."""
    frames, _, _ = sequence
    path = tmp_path / "seq.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (W, H), False)
    for _, _, gray in frames[:40]:
        writer.write(gray)
    writer.release()
    whole = list(iter_video_gray(path))
    assert len(whole) == 40
    for start, stop in [(16, 24), (32, None), (39, 45)]:
        part = list(iter_video_gray(path, start, stop))
        ref = whole[start:stop]
        assert [p[0] for p in part] == [r[0] for r in ref]
        assert [p[1] for p in part] == pytest.approx([r[1] for r in ref])
        assert all(np.array_equal(p[2], r[2]) for p, r in zip(part, ref, strict=True))
    src = functools.partial(iter_video_gray, path)
    assert [f for f, _, _ in src(38, None)] == [38, 39]


# --- realistic renders at 1080p (issue 13): few frames, rendered in memory -------------------

REALISTIC_YAML = Path(__file__).resolve().parents[3] / "config" / "realistic.yaml"


def _realistic_window(name, n_frames=5, duration_s=3.0, **synth):
    """``n_frames`` consecutive grey frames of a session of config/realistic.yaml, rendered in
    memory by the package's renderer (no stills, no codec), where the board is in view with
    at least 80 % of its corners visible; (frames, truth frames, true corners, board)."""
    from cvsflow.synth.frames import FrameEffects, Renderer
    from cvsflow.synth.motion import make_hand_motion
    from cvsflow.synth.render import realistic_truth
    from cvsflow.synth.session import make_rig, truth_tables
    from cvsflow.synth.spec import parse_session_config, random_streams

    with open(REALISTIC_YAML) as fh:
        cfg = yaml.safe_load(fh)["sessions"][name]
    cfg["synth"].update(duration_s=duration_s, **synth)
    spec = parse_session_config(cfg)
    rngs = random_streams(spec.seed)
    make_rig(spec, rngs["mounting"])
    renderer = Renderer(spec, rngs["background"])
    motion = make_hand_motion(rngs["motion"], spec.K, spec.image_size, spec.board.center_B(),
                              spec.effects.distance_m)
    truth, _, lighting, hands = realistic_truth(spec, rngs, motion)
    truth_frames, truth_corners = truth_tables(spec, truth)
    n = truth.corners_px.shape[1]
    ok = (truth_frames["n_visible"] >= 0.8 * n).to_numpy()
    start = next(i for i in range(len(ok) - n_frames) if ok[i:i + n_frames].all())
    frames = []
    for k in range(start, start + n_frames):
        fx = FrameEffects(hand=hands.get(int(truth.grip[k])), gain=float(truth.gain[k]),
                          analog_gain=float(truth.analog_gain[k]), wb_gains=truth.wb_gains[k])
        image = renderer.realistic_frame(motion, truth.t_s[k], truth.exposure_s[k],
                                         truth.blur_px[k], lighting, rngs["images"], fx)
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image
        frames.append((k - start, float(truth.t_s[k]), np.ascontiguousarray(gray)))
    window = truth_frames.iloc[start:start + n_frames].reset_index(drop=True)
    uv = truth.corners_px[start:start + n_frames]
    occluded = truth.occluded[start:start + n_frames] & truth.in_image[start:start + n_frames]
    return frames, window, uv, occluded, cfg["board"]


@pytest.mark.parametrize("name, synth", [
    ("fhd1080", {}),
    # The portrait session's hand never leaves the board (no frame a chessboard detector can
    # start from): here without it, for the portrait geometry and rolling shutter.
    ("portrait1080", {"occlusion": {"hand_share": 0.0}}),
])
def test_realistic_1080p_frames_keep_true_corners(name, synth):
    """On realistic 1920x1080 and 1080x1920 renders (wide lens, rolling shutter, a hand,
    exposure and colour drift, noise), every frame with 80 % of its corners visible is kept,
    corner k within 0.5 px of true corner k (no flips), at least 80 % of the visible corners
    kept, all of them where none is hidden."""
    frames, window, uv, occluded, board = _realistic_window(name, **synth)
    corners = extract_corners(frames, board, log_every=0)
    found = corners.groupby("frame")["found"].first()
    assert found.all(), corners.attrs["order_methods"]
    for f in range(len(frames)):
        rows = corners[corners["frame"] == f]
        ids = rows["corner"].to_numpy()
        err = np.linalg.norm(rows[["u_px", "v_px"]].to_numpy() - uv[f, ids], axis=1)
        assert err.max() < 0.5, (f, err.max())
        visible = int(window.loc[f, "n_visible"])
        assert len(ids) >= 0.8 * visible
        if not occluded[f].any() and visible == uv.shape[1]:
            assert len(ids) == uv.shape[1]


def test_waiting_frames_are_bounded_in_memory(monkeypatch):
    """Frames waiting for a board are bounded by bytes, not by the session's length: with room
    for 3 frames, a long run without a board leaves at most 3 waiting, and every frame gets
    its row (not_found / not_searched)."""
    import cvsflow.corners.track as pose

    blank = np.full((H, W), 128, np.uint8)
    monkeypatch.setattr(pose, "MAX_PENDING_BYTES", 3 * blank.nbytes)
    follower = pose._CornerFollower(BOARD, 5, 0.08, 3, None, True, None)
    decided = []
    for f in range(40):
        decided += follower.push(f, f / 30.0, blank.copy())
        assert len(follower.pending) <= 3
    decided += follower.finish()
    assert [d[0] for d in decided] == list(range(40))
    methods = {d[3] for d in decided}
    assert methods <= {"not_found", "not_searched"} and "not_searched" in methods
    # The search backs off: far fewer frames searched than frames seen.
    assert sum(d[3] == "not_found" for d in decided) <= 12


# --------------------------------------------------------------------------------------------
# extract_corners: the corners.parquet table


def test_extract_corners_table_schema_and_not_found_rows():
    """A sequence with a blank frame gives one found=False row (corner -1, NaN pixels) for it
    and 20 ordered rows for each board frame, with the contract's columns and dtypes."""
    frames = []
    truths = []
    for f, T in enumerate(random_board_poses(3, seed=20)):
        gray, uv = render_board(T, K_CENTRED, seed=f)
        frames.append((f, f / 30.0, gray))
        truths.append(uv)
    frames.insert(1, (99, 99 / 30.0, np.full((H, W), 128, np.uint8)))
    corners = extract_corners(iter(frames), BOARD, n_frames=4)
    assert list(corners.columns) == CORNER_COLUMNS
    assert corners["frame"].dtype == np.int64 and corners["corner"].dtype == np.int64
    assert corners["found"].dtype == bool
    blank = corners[corners["frame"] == 99]
    assert len(blank) == 1 and not blank["found"].iloc[0] and blank["corner"].iloc[0] == -1
    assert blank[["u_px", "v_px"]].isna().all().all()
    for f, uv in enumerate(truths):
        block = corners[corners["frame"] == f]
        assert block["corner"].tolist() == list(range(20)) and block["found"].all()
        np.testing.assert_allclose(block[["u_px", "v_px"]].to_numpy(), uv, atol=0.3)
    assert corners.attrs["n_found"] == 3 and corners.attrs["n_frames"] == 4


def test_extract_corners_rejects_a_colour_frame():
    """A frame that is not 8-bit grayscale is an InputError naming the frame."""
    bad = np.zeros((H, W, 3), np.uint8)
    with pytest.raises(InputError, match="frame 5"):
        extract_corners([(5, 0.1, bad)], BOARD)


def test_extract_corners_survives_an_opencv_error_on_one_frame(monkeypatch):
    """An OpenCV error on one frame makes it found=False (counted as cv_error); the other
    frames keep their boards."""
    import cvsflow.corners.track as pose

    T = board_centre_pose([0.1, 0.0, 0.0], [0.0, 0.0, 1.2])
    frames = [(i, i / 30.0, render_board(T, K_CENTRED, seed=i)[0]) for i in range(4)]
    real = pose.detect_corners

    def failing(gray, *args, **kwargs):
        if gray is frames[2][2]:
            raise cv2.error("cornerSubPix: initial corner is outside the image")
        return real(gray, *args, **kwargs)

    monkeypatch.setattr(pose, "detect_corners", failing)
    corners = extract_corners(frames, BOARD, track=False, log_every=0)
    found = corners.groupby("frame")["found"].first()
    assert found.tolist() == [True, True, False, True]
    assert corners.attrs["order_methods"].get("cv_error") == 1


def test_a_hand_over_the_board_keeps_the_visible_corners_with_true_indices():
    """A tracked board that a hand (a dark polygon) partly covers stays found: the corners the
    hand leaves are kept with their true indices (within 0.5 px), hidden ones are dropped."""
    from tests.helpers.board_images import render_board_distorted

    size, K = (1280, 720), np.array([[900.0, 0.0, 640.0], [0.0, 900.0, 360.0], [0.0, 0.0, 1.0]])
    frames, truths, hands = [], [], []
    for i in range(8):
        T = board_centre_pose([0.2, -0.15, 0.0], [-0.05 + 0.004 * i, 0.02, 1.2], BOARD_10x7)
        hand = None
        if i >= 4:  # a hand over the right third of the board
            _, uv = render_board_distorted(T, K, WIDE_DIST, size, BOARD_10x7)
            x0 = uv[:, 0].min() + 0.66 * np.ptp(uv[:, 0])
            hand = np.array([[x0, 0], [size[0], 0], [size[0], size[1]], [x0, size[1]]])
        gray, uv = render_board_distorted(T, K, WIDE_DIST, size, BOARD_10x7, blur_sigma=1.0,
                                          occluder=hand, seed=i)
        frames.append((i, i / 30.0, gray))
        truths.append(uv)
        hands.append(hand)
    corners = extract_corners(frames, BOARD_10x7, log_every=0)
    found = corners.groupby("frame")["found"].first()
    assert found.all()
    for i in range(4, 8):
        rows = corners[corners["frame"] == i]
        uv_true = truths[i][rows["corner"].to_numpy()]
        assert np.linalg.norm(rows[["u_px", "v_px"]].to_numpy() - uv_true, axis=1).max() < 0.5
        visible = truths[i][:, 0] < hands[i][0, 0] - 20
        assert 0.8 * visible.sum() <= len(rows) < len(truths[i])
        assert (uv_true[:, 0] < hands[i][0, 0]).all()


def test_progress_counts_every_frame_in_one_pass_and_across_workers(tmp_path):
    """progress(n) sees every frame read: after each one in a single pass, the workers' shared
    count (rising to the total) from several processes; the table is the same either way."""
    import functools

    from cvsflow.corners import extract_corners_parallel
    from cvsflow.io.media import iter_video_gray
    from tests.helpers.board_images import write_h264

    path = tmp_path / "v.mp4"
    write_h264(path, 90, gop=15)
    source = functools.partial(iter_video_gray, path)
    single, parallel = [], []
    one = extract_corners_parallel(source, 90, BOARD, n_workers=1, restart_every=45, progress=single.append,
                                   log_every=0)
    two = extract_corners_parallel(source, 90, BOARD, n_workers=2, restart_every=45,
                                   progress=parallel.append, log_every=0)
    assert single == list(range(1, 91))
    assert parallel[-1] == 90 and parallel == sorted(parallel)
    plain = extract_corners_parallel(source, 90, BOARD, n_workers=2, restart_every=45, log_every=0)
    pd.testing.assert_frame_equal(two, plain)
    pd.testing.assert_frame_equal(one.reset_index(drop=True), plain.reset_index(drop=True))
