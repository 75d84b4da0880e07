"""Tests of cvsflow.io.raw_video and ``cvsflow remux``: raw H.264 streams given frame times."""

from __future__ import annotations

import av
import numpy as np
import pytest

from cvsflow.cli import main
from cvsflow.corners.extract import extract_corners
from cvsflow.exceptions import InputError
from cvsflow.io.media import iter_video_gray, video_timing
from cvsflow.io.raw_video import read_timecodes_v2, remux_with_times
from tests.helpers.board_images import BOARD, write_h264


def _raw_h264(path, n=40, b_frames=False):
    """A bare Annex B H.264 stream, as a Raspberry Pi camera writes (no B-frames by default)."""
    write_h264(path, n, fmt="h264", gop=15, b_frames=b_frames)


def _luma(path):
    """Each decoded frame's Y plane as the codec gives it."""
    container = av.open(str(path))
    try:
        return [np.frombuffer(f.planes[0], np.uint8).reshape(-1, f.planes[0].line_size)[:, :f.width]
                for f in container.decode(video=0)]
    finally:
        container.close()


def _camera_times_s(n, seed=0):
    """A webcam's times: 30 fps with 2 ms jitter, frame 20 dropped, from a clock at 1234.5 s."""
    rng = np.random.default_rng(seed)
    k = np.arange(n + 1, dtype=float)
    k = np.delete(k, 20)
    return 1234.5 + k / 30.0 + rng.uniform(-0.002, 0.002, n)


def test_raw_stream_is_refused_with_the_remux_command(tmp_path):
    """A bare stream has no frame times: the error names the file and the fix."""
    raw = tmp_path / "cam.h264"
    _raw_h264(raw, n=10)
    for call in (video_timing, lambda p: list(iter_video_gray(p))):
        with pytest.raises(InputError, match=r"cam.h264: its 10 frames carry no timestamps.*cvsflow remux"):
            call(raw)


def test_remux_gives_the_camera_s_times_and_keeps_every_pixel(tmp_path, capsys):
    """Timestamps file -> MP4: the container's times are the camera's (from 0, to 11 us), the
    drop shows as a dropped frame, the pixels are the raw stream's bit for bit (no
    re-encoding), and the corners stage finds the board in every frame."""
    raw, mp4, pts = tmp_path / "cam.h264", tmp_path / "cam.mp4", tmp_path / "cam_pts.txt"
    n = 40
    _raw_h264(raw, n=n)
    t_cam = _camera_times_s(n)
    pts.write_text("# timecode format v2\n" + "".join(f"{1000 * t:.3f}\n" for t in t_cam))
    assert main(["remux", str(raw), "--timestamps", str(pts), "--out", str(mp4)]) == 0
    assert "40 frames" in capsys.readouterr().out
    timing = video_timing(mp4)
    np.testing.assert_allclose(timing["t_s"], t_cam - t_cam[0], atol=2e-5)
    assert timing["n_dropped"] == 1 and timing["gaps"] == [[19, 1]]
    frames = list(iter_video_gray(mp4))
    assert [f for f, _, _ in frames] == list(range(n))
    for a, b in zip(_luma(mp4), _luma(raw), strict=True):
        np.testing.assert_array_equal(a, b)
    chunked = [g for a, b in ((0, 15), (15, None)) for _, _, g in iter_video_gray(mp4, a, b)]
    assert all(np.array_equal(a, b) for (_, _, a), b in zip(frames, chunked, strict=True))
    corners = extract_corners(iter(frames), BOARD, log_every=0)
    assert corners.groupby("frame")["found"].first().all()


def test_remux_at_a_nominal_rate(tmp_path):
    raw, mp4 = tmp_path / "cam.h264", tmp_path / "cam.mp4"
    _raw_h264(raw, n=12)
    done = remux_with_times(raw, mp4, fps=25.0)
    assert done["n_frames"] == 12 and done["source"] == "fps"
    np.testing.assert_allclose(video_timing(mp4)["t_s"], np.arange(12) / 25.0, atol=2e-5)


@pytest.mark.parametrize("case", ["b_frames", "count", "exists", "both", "timed"])
def test_remux_refuses_what_it_cannot_do_and_leaves_no_file(tmp_path, case):
    raw, mp4 = tmp_path / "cam.h264", tmp_path / "cam.mp4"
    _raw_h264(raw, n=12, b_frames=case == "b_frames")
    kwargs = {"fps": 30.0}
    match = {"b_frames": "B-frames", "count": "12 frames, but 11 timestamps",
             "exists": "cam.mp4: exists", "both": "either as a frame rate",
             "timed": "carry timestamps already"}[case]
    src = raw
    if case == "count":
        kwargs = {"timestamps_s": np.arange(11) / 30.0}
    elif case == "exists":
        mp4.write_bytes(b"the user's file")
    elif case == "both":
        kwargs = {"fps": 30.0, "timestamps_s": np.arange(12) / 30.0}
    elif case == "timed":
        src = tmp_path / "timed.mp4"
        remux_with_times(raw, src, fps=30.0)
    with pytest.raises(InputError, match=match):
        remux_with_times(src, mp4, **kwargs)
    if case == "exists":
        assert mp4.read_bytes() == b"the user's file"
    else:
        assert not mp4.exists()


@pytest.mark.parametrize("text, match", [
    ("# timecode format v2\n0\n33.3\nabc\n", r"line 4: 'abc' is not a time in ms"),
    ("0\n33.3\n33.3\n", r"frame 2 at 33.3 ms does not follow frame 1"),
    ("# timecode format v2\n5\n", r"1 frame times"),
])
def test_bad_timestamps_files_name_the_line(tmp_path, text, match):
    path = tmp_path / "pts.txt"
    path.write_text(text)
    with pytest.raises(InputError, match=match):
        read_timecodes_v2(path)


def test_init_names_remux_for_a_folder_with_only_a_raw_stream(tmp_path):
    from cvsflow.cli.init import build_session_config

    (tmp_path / "cam.h264").write_bytes(b"\x00\x00\x00\x01")
    session, notes = build_session_config(tmp_path)
    assert session["video"] == "TODO"
    assert any("cam.h264: a raw stream without frame times: `cvsflow remux" in n for n in notes)
