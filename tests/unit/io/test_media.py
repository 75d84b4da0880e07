"""Tests of cvsflow.io.media: PyAV decoding, container timestamps, frame counts, bad files."""

from __future__ import annotations

import functools
from fractions import Fraction

import av
import cv2
import numpy as np
import pandas as pd
import pytest

from cvsflow.corners.extract import extract_corners, extract_corners_parallel, summarise_corners
from cvsflow.exceptions import InputError
from cvsflow.io.media import iter_video_gray, video_info, video_timing
from tests.helpers.board_images import (
    BOARD,
    K_DRIFT,
    board_centre_pose,
    drifting_board_frame,
    render_board,
    write_h264,
)

K = K_DRIFT
_board_frame = drifting_board_frame


def _write_vfr_mp4(path, pts_s, time_base=Fraction(1, 90000)):
    """H.264 (or MPEG-4) mp4 whose frame k has presentation time pts_s[k] (s)."""
    container = av.open(str(path), "w")
    try:
        stream = container.add_stream("libx264", rate=30)
    except Exception:  # noqa: BLE001 - an FFmpeg build without x264
        stream = container.add_stream("mpeg4", rate=30)
    stream.width, stream.height, stream.pix_fmt = 640, 480, "yuv420p"
    stream.time_base = time_base
    stream.codec_context.time_base = time_base
    for k, t in enumerate(pts_s):
        frame = av.VideoFrame.from_ndarray(cv2.cvtColor(_board_frame(k), cv2.COLOR_GRAY2BGR),
                                           format="bgr24").reformat(format="yuv420p")
        frame.pts = int(round(t / time_base))
        frame.time_base = time_base
        for packet in stream.encode(frame):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


def _truncated_avi(path, n_written=300, size=(320, 240)):
    """MJPEG AVI whose header states n_written frames, cut to about half its bytes."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30, size)
    for i in range(n_written):
        writer.write(cv2.cvtColor(cv2.resize(_board_frame(i % 60), size), cv2.COLOR_GRAY2BGR))
    writer.release()
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def test_vfr_times_come_from_the_container_and_drops_are_counted(tmp_path):
    """Jittered presentation times on a fine time base come back to the tick, frames keep
    consecutive indices, and a gap of three periods counts two dropped frames."""
    rng = np.random.default_rng(5)
    n = 40
    t = np.arange(n + 2) / 30.0 + rng.uniform(-0.004, 0.004, n + 2)
    t[0] = 0.0
    t = np.delete(t, [21, 22])  # two frames dropped after frame 20
    path = tmp_path / "vfr.mp4"
    _write_vfr_mp4(path, t)
    frames = list(iter_video_gray(path))
    assert [f[0] for f in frames] == list(range(n))
    got = np.array([f[1] for f in frames])
    assert np.abs(got - (t - t[0])).max() < 1.5e-5
    timing = video_timing(path)
    assert timing["n_frames"] == n
    assert timing["n_dropped"] == 2 and timing["gaps"] == [[20, 2]]
    assert video_info(path)["n_frames"] == n
    assert frames[3][2].shape == (480, 640) and frames[3][2].dtype == np.uint8


def test_seeking_is_exact_on_a_vfr_video(tmp_path):
    """iter_video_gray(path, start, stop) gives exactly the frames, times and pixels of a full
    read, also starting between key frames."""
    t = np.arange(30) / 30.0 + np.random.default_rng(6).uniform(-0.003, 0.003, 30)
    t[0] = 0.0
    path = tmp_path / "vfr.mp4"
    _write_vfr_mp4(path, t)
    whole = list(iter_video_gray(path))
    for start, stop in [(0, 5), (7, 19), (13, None), (29, None), (30, None)]:
        part = list(iter_video_gray(path, start, stop))
        ref = whole[start:stop]
        assert [p[0] for p in part] == [r[0] for r in ref]
        assert all(p[1] == r[1] and np.array_equal(p[2], r[2]) for p, r in zip(part, ref, strict=True))


def test_header_count_larger_than_decoded_is_reported_and_chunks_equal_one_pass(tmp_path):
    """A cut file whose header states 300 frames: both counts reported, and the chunked
    two-process extraction gives the single-pass table (chunks cut on the demuxed count)."""
    path = tmp_path / "cut.avi"
    _truncated_avi(path)
    info, timing = video_info(path), video_timing(path)
    decoded = sum(1 for _ in iter_video_gray(path))
    assert info["n_frames_header"] == 300
    assert info["n_frames"] == timing["n_frames"] == decoded
    assert 100 < decoded < 200
    source = functools.partial(iter_video_gray, path)
    single = extract_corners(source(0, None), BOARD, restart_every=40, log_every=0)
    parallel = extract_corners_parallel(source, info["n_frames"], BOARD, n_workers=2,
                                        restart_every=40, log_every=0)
    pd.testing.assert_frame_equal(single, parallel)
    summary = summarise_corners(parallel, timing)
    assert summary["n_frames_header"] == 300
    assert summary["n_frames_decoded"] == summary["n_frames_demuxed"] == decoded
    assert summary["n_found"] > 0


@pytest.mark.parametrize("kind", ["folder", "text", "missing"])
def test_bad_video_files_raise_input_error_naming_the_file(tmp_path, kind):
    """A folder, a file that is not a video and a missing file are InputErrors naming it."""
    path = tmp_path / "board.mp4"
    if kind == "folder":
        path.mkdir()
    elif kind == "text":
        path.write_text("not a video\n")
    for call in (video_info, video_timing, lambda p: list(iter_video_gray(p))):
        with pytest.raises(InputError, match="board.mp4"):
            call(path)


def _write_rotated_mp4(path, frames, rotation_deg):
    """H.264 mp4 of grey frames stored as given, with a display rotation (a phone held upright)."""
    container = av.open(str(path), "w")
    stream = container.add_stream("libx264", rate=30)
    stream.height, stream.width = frames[0].shape
    stream.pix_fmt = "yuv420p"
    stream.set_display_rotation(rotation_deg)
    for img in frames:
        frame = av.VideoFrame.from_ndarray(cv2.cvtColor(img, cv2.COLOR_GRAY2BGR), format="bgr24")
        for packet in stream.encode(frame.reformat(format="yuv420p")):
            container.mux(packet)
    for packet in stream.encode():
        container.mux(packet)
    container.close()


@pytest.mark.parametrize("rotation_deg", [90, -90, 180])
def test_display_rotation_is_applied_as_players_apply_it(tmp_path, rotation_deg):
    """Frames stored on their side come out upright: as OpenCV's auto-orientation (FFmpeg's
    rule) shows them, with video_size's width and height swapped for a quarter turn, and the
    board's corners found in the upright frame where they are in the upright truth."""
    from cvsflow.io.media import video_size

    T = board_centre_pose([0.1, 0.05, 0.0], [-0.05, 0.02, 1.3])
    img, truth = render_board(T, K, seed=1)
    path = tmp_path / "phone.mp4"
    _write_rotated_mp4(path, [img] * 3, rotation_deg)
    size = video_size(path)
    quarter = rotation_deg % 180 != 0
    assert (size["width"], size["height"]) == ((480, 640) if quarter else (640, 480))
    assert (size["stored_width"], size["stored_height"]) == (640, 480)
    assert size["rotation_deg"] == rotation_deg % 360
    assert video_info(path)["width"] == size["width"]
    frames = list(iter_video_gray(path))
    assert len(frames) == 3 and frames[0][2].shape == (size["height"], size["width"])
    cap = cv2.VideoCapture(str(path))
    ok, bgr = cap.read()
    auto = cap.get(cv2.CAP_PROP_ORIENTATION_AUTO)
    cap.release()
    assert ok and auto == 1.0
    reference = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert reference.shape == frames[0][2].shape
    assert np.abs(reference.astype(int) - frames[0][2]).mean() < 2.0  # the same codec's pixels
    # the stored frame turned by np.rot90's k = rotation / 90 is what is read
    k = (rotation_deg // 90) % 4
    stored = next(av.open(str(path)).decode(video=0)).to_ndarray(format="gray")
    np.testing.assert_array_equal(frames[0][2], np.rot90(stored, k))
    corners = extract_corners(iter(frames), BOARD, track=False)
    found = corners[corners["found"]]
    assert found["frame"].nunique() == 3
    # truth turned the same way: a pixel (u, v) of the stored image after k quarter turns
    h, w = img.shape
    uv = truth.reshape(-1, 2)
    for _ in range(k):
        uv = np.column_stack([uv[:, 1], w - 1 - uv[:, 0]])
        w, h = h, w
    got = found[found["frame"] == 0].sort_values("corner")[["u_px", "v_px"]].to_numpy()
    # the corner order may start at either end of the board; compare as sets of points
    d = np.linalg.norm(got[:, None] - uv[None], axis=-1).min(axis=1)
    assert np.median(d) < 0.2


def test_image_size_check_names_a_quarter_turn_and_a_resolution_change():
    from cvsflow.exceptions import ImageSizeError
    from cvsflow.plausibility.checks import check_image_size

    camera = {"width": 1080, "height": 1920}
    check_image_size(camera, 1080, 1920)
    check_image_size({"K": [[1, 0, 0], [0, 1, 0], [0, 0, 1]]}, 640, 480)  # no size stated: nothing to check
    with pytest.raises(ImageSizeError, match=r"phone.mp4: frames are 1920x1080 px.*cam.yaml.*1080x1920.*quarter"):
        check_image_size(camera, 1920, 1080, "cam.yaml", "phone.mp4")
    with pytest.raises(ImageSizeError, match=r"1280x720 px.*do not carry over between resolutions"):
        check_image_size(camera, 1280, 720, "cam.yaml", "webcam.mp4")
    with pytest.raises(ImageSizeError, match="display rotation 90 deg"):
        check_image_size(camera, 1920, 1080, rotation_deg=90.0)


def _damaged_mp4(path, n_frames=120, gop=20):
    """H.264 mp4 of a drifting board (key frame every ``gop``) with bytes overwritten in the
    middle of its media data (a bad card sector): some packets no longer decode."""
    write_h264(path, n_frames, gop=gop)
    data = bytearray(path.read_bytes())
    rng = np.random.default_rng(3)
    for k in range(24):  # the moov index is at the end: these land in mdat
        at = int(0.4 * len(data)) + 211 * k
        data[at:at + 24] = rng.integers(0, 256, 24, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))


def test_a_damaged_recording_loses_its_bad_frames_only_and_chunks_equal_one_pass(tmp_path):
    """Packets the decoder refuses cost their frames, not the rest of the video (the whole
    pass used to stop at the first): every frame index comes out, the refused ones as None
    rows with found=False counted as ``undecodable``, the board is found again after them,
    and the two-process table equals the single pass."""
    path = tmp_path / "damaged.mp4"
    _damaged_mp4(path)
    timing = video_timing(path)
    frames = list(iter_video_gray(path, undecodable=True))
    assert [f for f, _, _ in frames] == list(range(timing["n_frames"]))
    np.testing.assert_allclose([t for _, t, _ in frames], timing["t_s"])
    bad = [f for f, _, g in frames if g is None]
    assert 0 < len(bad) < 40
    assert sum(g is not None for f, _, g in frames if f > max(bad)) > 10  # decoding went on
    kept = list(iter_video_gray(path))
    assert [f for f, _, _ in kept] == [f for f, _, g in frames if g is not None]
    chunked = [f for a, b in [(0, 50), (50, 90), (90, None)]
               for f, _, _ in iter_video_gray(path, a, b, undecodable=True)]
    assert chunked == list(range(timing["n_frames"]))
    source = functools.partial(iter_video_gray, path, undecodable=True)
    single = extract_corners(source(0, None), BOARD, restart_every=40, log_every=0)
    parallel = extract_corners_parallel(source, timing["n_frames"], BOARD, n_workers=2,
                                        restart_every=40, log_every=0)
    pd.testing.assert_frame_equal(single, parallel)
    found = parallel.groupby("frame")["found"].first()
    assert not found[bad].any()
    assert found[found.index > max(bad)].sum() > 10
    summary = summarise_corners(parallel, timing)
    assert summary["n_undecodable"] == summary["frames_by_method"]["undecodable"] == len(bad)
    assert summary["n_frames_decoded"] == timing["n_frames"] - len(bad)


def test_a_video_of_which_nothing_decodes_is_an_input_error(tmp_path):
    """Every packet refused: an InputError naming the file, not an empty corners table."""
    path = tmp_path / "noise.mp4"
    _damaged_mp4(path, n_frames=30, gop=30)
    data = bytearray(path.read_bytes())
    moov = data.rfind(b"moov")
    rng = np.random.default_rng(4)
    start = data.find(b"mdat") + 8
    data[start:moov - 8] = rng.integers(0, 256, moov - 8 - start, dtype=np.uint8).tobytes()
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match="noise.mp4.*not one frame decodes"):
        list(iter_video_gray(path))


def test_an_mp4_cut_off_before_its_index_says_so(tmp_path):
    """A phone recording that stopped before the index was written (moov at the end): the
    error names the file and the likely cause."""
    path = tmp_path / "cut.mp4"
    _write_vfr_mp4(path, np.arange(20) / 30.0)
    data = path.read_bytes()
    path.write_bytes(data[: data.rfind(b"moov") - 8])
    for call in (video_info, video_timing, lambda p: list(iter_video_gray(p))):
        with pytest.raises(InputError, match="cut.mp4.*cut off has no index"):
            call(path)


def test_an_empty_cut_or_foreign_still_cannot_be_decoded_and_says_why(tmp_path):
    """read_gray names an empty file, a JPEG or PNG whose data ends early (OpenCV decoded the cut
    JPEG in silence, grey below the cut, and the calibration said 'no chessboard found') and a
    file that is no image; read_stills leaves them out with that reason and reads the rest."""
    from cvsflow.io.media import read_gray, read_stills

    rng = np.random.default_rng(0)
    gray = rng.integers(0, 255, (120, 160), dtype=np.uint8)
    cv2.imwrite(str(tmp_path / "a_good.png"), gray)
    for name in ("cut.jpg", "cut.png"):
        cv2.imwrite(str(tmp_path / name), gray)
        data = (tmp_path / name).read_bytes()
        (tmp_path / name).write_bytes(data[: len(data) * 6 // 10])
    (tmp_path / "empty.jpg").write_bytes(b"")
    (tmp_path / "notes.png").write_text("not an image")
    cases = {"cut.jpg": r"cannot be decoded \(truncated\? image file is truncated",
             "cut.png": r"cannot be decoded \(truncated\? image file is truncated",
             "empty.jpg": r"empty file \(0 bytes\), cannot be decoded as an image",
             "notes.png": r"cannot be decoded as an image$"}
    for name, match in cases.items():
        with pytest.raises(InputError, match=rf"{tmp_path / name}: {match}"):
            read_gray(tmp_path / name)
    images, unreadable = read_stills(sorted(tmp_path.iterdir()))
    assert [n for n, _ in images] == ["a_good.png"] and np.array_equal(images[0][1], gray)
    assert [n for n, _ in unreadable] == ["cut.jpg", "cut.png", "empty.jpg", "notes.png"]
    assert unreadable[2][1] == "empty file (0 bytes), cannot be decoded as an image"
