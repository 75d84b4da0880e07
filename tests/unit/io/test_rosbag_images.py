"""An image topic of a bag as a frame source: the yac frames from ROS 1, sqlite3 and MCAP bags are
the files' frames exactly (JPEG bytes never re-encoded), raw encodings, and each bad input named."""

from __future__ import annotations

import functools
import logging
import tracemalloc

import cv2
import numpy as np
import pytest

from cvsflow.corners import extract_corners_parallel
from cvsflow.exceptions import BagError, ImageDecodeError, TopicNotFoundError, TopicTypeError, ZeroStampError
from cvsflow.io.frames import frame_list, iter_frames_gray
from cvsflow.io.rosbag import open_bag
from cvsflow.io.rosbag_images import (
    bag_frame_list,
    bag_frames_info,
    decode_compressed_image,
    iter_bag_gray,
    iter_bag_images,
)
from tests.helpers.bags import IMAGE_DELAY_NS, JPEG_TOPIC, RAW_TOPIC, Msg, write_bag, yac_frames, yac_messages
from tests.helpers.board_images import BOARD, drifting_board_frame
from tests.helpers.real_data import REAL_DATA

YAC = REAL_DATA / "yac-mocap-aprilgrid"
T0 = 1_700_000_000_123_456_789
rng = np.random.default_rng(7)


@pytest.fixture(scope="module", params=["ros1", "sqlite3", "mcap"])
def yac_bag(request, tmp_path_factory):
    """The yac frames as CompressedImage (the JPEG files' bytes) and bgr8 Image topics."""
    if not (YAC / "cam0" / "data").is_dir():
        pytest.skip(f"real data not available ({YAC})")
    return write_bag(tmp_path_factory.mktemp(request.param) / "yac", request.param,
                     yac_messages(YAC, poses=False, tf=False))  # fmt: skip


def test_compressed_frames_are_the_folders(yac_bag):
    """(frame, t_s, gray) as the frame folder gives them; the frame list's exact ns likewise; the
    message's bytes are the JPEG file's, byte for byte."""
    got = list(iter_bag_gray(yac_bag, JPEG_TOPIC))
    ref = list(iter_frames_gray(YAC / "cam0"))
    assert len(got) == len(ref) == 30
    for (f, t, g), (fr, tr, gr) in zip(got, ref, strict=True):
        assert (f, t) == (fr, tr) and g.dtype == np.uint8 and np.array_equal(g, gr)
    frames = bag_frame_list(yac_bag, JPEG_TOPIC)
    assert frames[["frame", "t_ns", "t_s"]].equals(frame_list(YAC / "cam0")[["frame", "t_ns", "t_s"]])
    assert (frames["t_receive_ns"] - frames["t_ns"] == IMAGE_DELAY_NS).all()
    files = dict(yac_frames(YAC))
    with open_bag(yac_bag) as b:
        for _i, t_ns, _rx, msg in b.messages(JPEG_TOPIC):
            assert bytes(msg.data) == files[t_ns].read_bytes()


def test_modes_and_raw_frames(yac_bag):
    """bgr of the JPEG topic is cv2.imread's colour image; the raw bgr8 topic gives the pixels
    back, and its gray is cvtColor of them (not the JPEG decoded to grey: libjpeg differs)."""
    path = yac_frames(YAC)[3][1]
    [(_f, _t, bgr)] = list(iter_bag_images(yac_bag, JPEG_TOPIC, "bgr", start=3, stop=4))
    assert np.array_equal(bgr, cv2.imread(str(path), cv2.IMREAD_COLOR))
    [(_f, _t, raw)] = list(iter_bag_images(yac_bag, RAW_TOPIC, "bgr", start=3, stop=4))
    [(_f, _t, gray)] = list(iter_bag_images(yac_bag, RAW_TOPIC, "gray", start=3, stop=4))
    assert np.array_equal(raw, bgr) and np.array_equal(gray, cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY))
    assert not np.array_equal(gray, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE))
    info = bag_frames_info(yac_bag, RAW_TOPIC)
    assert (info["n_frames"], info["width"], info["height"], info["encoding"]) == (30, 640, 480, "bgr8")


def test_receive_times_and_missing_topic(yac_bag):
    got = [t for _f, t, _g in iter_bag_images(yac_bag, JPEG_TOPIC, time="receive", stop=3)]
    assert got == [t + IMAGE_DELAY_NS for t, _p in yac_frames(YAC)[:3]]
    with pytest.raises(TopicNotFoundError) as exc:
        next(iter_bag_gray(yac_bag, "/cam1/image_raw"))
    for listed in (f"{RAW_TOPIC}  ", "sensor_msgs/msg/CompressedImage", "(30 messages)"):
        assert listed in str(exc.value)


def test_zero_stamps_say_receive(tmp_path):
    if not (YAC / "cam0" / "data").is_dir():
        pytest.skip(f"real data not available ({YAC})")
    msgs = yac_messages(YAC, raw=False, poses=False, tf=False, zero_stamps=True, n_frames=3)
    bag = write_bag(tmp_path / "zero", "mcap", msgs)
    with pytest.raises(ZeroStampError, match=r"message 0: its header stamp is zero.*time: receive.*--receive-time"):
        next(iter_bag_gray(bag, JPEG_TOPIC))
    got = [t for _f, t, _g in iter_bag_images(bag, JPEG_TOPIC, time="receive")]
    assert got == [t + IMAGE_DELAY_NS for t, _p in yac_frames(YAC)[:3]]


# ----------------------------------------------------------------- synthetic bags (no data needed)


def _img(i, encoding, pixels, topic="/cam/image_raw", **kw):
    return Msg(T0 + i * 33_000_000 + 2_000_000, topic, "sensor_msgs/msg/Image",
               {"t_ns": T0 + i * 33_000_000, "frame_id": "cam", "encoding": encoding, "pixels": pixels, **kw})


def _jpeg(i, data, fmt="jpeg", topic="/cam/compressed", t_ns=None):
    t = T0 + i * 33_000_000 if t_ns is None else t_ns
    return Msg(T0 + i * 33_000_000 + 2_000_000, topic, "sensor_msgs/msg/CompressedImage",
               {"t_ns": t, "frame_id": "cam", "format": fmt, "data": data})


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
def test_raw_encodings(tmp_path, storage):
    """Colour orders, 16 bits in both byte orders, padded rows, Bayer RGGB as OpenCV's BayerBG."""
    bgr = rng.integers(0, 256, (6, 5, 3), dtype=np.uint8)
    px16 = rng.integers(0, 65536, (6, 5), dtype=np.uint16)
    mosaic = np.zeros((16, 16), np.uint8)
    mosaic[0::2, 0::2] = 200  # the R sites of RGGB: a red scene
    cases = {"bgr8": bgr, "rgb8": bgr[..., ::-1], "bgra8": cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA),
             "rgba8": cv2.cvtColor(bgr, cv2.COLOR_BGR2RGBA)}  # fmt: skip
    msgs = [_img(0, enc, px, topic=f"/c/{enc}") for enc, px in cases.items()]
    msgs += [_img(0, "bgr8", bgr, topic="/padded", step=20), _img(0, "bayer_rggb8", mosaic, topic="/bayer"),
             _img(0, "mono16", px16.astype("<u2"), topic="/le"),
             _img(0, "mono16", px16.astype(">u2"), topic="/be", is_bigendian=1)]  # fmt: skip
    bag = write_bag(tmp_path / "b", storage, msgs)

    def one(topic, mode):
        [(_f, _t, img)] = list(iter_bag_images(bag, topic, mode))
        return img

    for enc in cases:
        assert np.array_equal(one(f"/c/{enc}", "bgr"), bgr), enc
        assert np.array_equal(one(f"/c/{enc}", "gray"), cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)), enc
    assert np.array_equal(one("/padded", "bgr"), bgr)
    b, g, r = one("/bayer", "bgr")[4:-4, 4:-4].reshape(-1, 3).mean(axis=0)
    assert r > 150 and b < 20 and g < 20
    for topic in ("/le", "/be"):
        assert np.array_equal(one(topic, "unchanged"), px16)
        assert np.array_equal(one(topic, "gray"), np.round(px16 / 257.0).astype(np.uint8))


def test_encodings_opencv_cannot_decode_are_named(tmp_path):
    depth = rng.random((8, 9), dtype=np.float32)
    msgs = [_img(0, "32FC1", depth), _img(1, "32FC1", depth), _img(0, "nv12", np.zeros((12, 8), np.uint8), "/nv"),
            _jpeg(0, b"\x00\x00\x00\x01\x67h264", "h264"), _jpeg(0, b"\x00" * 12 + b"\x89PNG", "16UC1; compressedDepth",
                                                                "/depth/compressed")]  # fmt: skip
    bag = write_bag(tmp_path / "b", "mcap", msgs)
    [(_f, _t, u), _] = list(iter_bag_images(bag, "/cam/image_raw", "unchanged"))
    assert u.dtype == np.float32 and np.array_equal(u, depth)
    with pytest.raises(ImageDecodeError, match=r"topic /cam/image_raw, message 0: encoding '32FC1': OpenCV has no "
                                               r"conversion of it to 'gray'") as exc:  # fmt: skip
        next(iter_bag_gray(bag, "/cam/image_raw"))
    assert (exc.value.topic, exc.value.index, exc.value.encoding) == ("/cam/image_raw", 0, "32FC1")
    with pytest.raises(ImageDecodeError, match="encoding 'nv12'"):
        next(iter_bag_gray(bag, "/nv"))
    with pytest.raises(ImageDecodeError, match=r"encoding 'h264': 9 bytes of no format OpenCV decodes \(first bytes 00 "
                                               r"00 00 01"):  # fmt: skip
        next(iter_bag_gray(bag, "/cam/compressed"))
    with pytest.raises(ImageDecodeError, match="compressedDepth"):
        next(iter_bag_gray(bag, "/depth/compressed"))
    pose = Msg(T0, "/pose", "geometry_msgs/msg/PoseStamped", {"t_ns": T0, "frame_id": "w", "v": [0, 0, 0, 0, 0, 0, 1]})
    other = write_bag(tmp_path / "p", "ros1", [pose, _img(0, "mono8", depth.astype(np.uint8))])
    with pytest.raises(TopicTypeError, match=r"/pose is geometry_msgs/msg/PoseStamped, not an image topic.*the topics "
                                             r"that are:\n  /cam/image_raw"):  # fmt: skip
        next(iter_bag_gray(other, "pose"))


def test_damaged_frames_cost_their_frame(tmp_path, caplog):
    """A JPEG cut short (no end marker) or refused is left out and named, as in a frame folder;
    times that go back are an error naming both messages."""
    jpg = [cv2.imencode(".jpg", drifting_board_frame(k))[1].tobytes() for k in range(4)]
    msgs = [_jpeg(0, jpg[0]), _jpeg(1, jpg[1][: len(jpg[1]) // 2]), _jpeg(2, jpg[2]), _jpeg(3, jpg[3])]
    bag = write_bag(tmp_path / "b", "sqlite3", msgs)
    with caplog.at_level(logging.WARNING):
        got = list(iter_bag_gray(bag, "/cam/compressed"))
    assert [f for f, _t, _g in got] == [0, 2, 3]
    assert "message 1 (JPEG data of" in caplog.text and "without its end marker" in caplog.text
    assert [g is None for _f, _t, g in iter_bag_gray(bag, "/cam/compressed", undecodable=True)] == [0, 1, 0, 0]
    back = write_bag(tmp_path / "back", "ros1", [_jpeg(0, jpg[0]), _jpeg(1, jpg[1], t_ns=T0 - 5)])
    with pytest.raises(BagError, match=r"message 1: its time .* goes back from message 0's"):
        list(iter_bag_gray(back, "/cam/compressed"))
    assert decode_compressed_image(type("M", (), {"format": "png", "data": np.frombuffer(
        cv2.imencode(".png", drifting_board_frame(0))[1].tobytes(), np.uint8)})(), "gray").shape == (480, 640)


def test_corners_stage_runs_on_a_bag(tmp_path):
    """extract_corners_parallel on a bag's frame source (two chunks) as on the same frames in a folder."""
    msgs = [_img(k, "mono8", drifting_board_frame(k)) for k in range(6)]
    bag = write_bag(tmp_path / "b", "mcap", msgs)
    source = functools.partial(iter_bag_gray, bag, "/cam/image_raw", undecodable=True)
    got = extract_corners_parallel(source, 6, BOARD, n_workers=2, restart_every=3)
    ref = extract_corners_parallel(lambda a, b: ((k, m.fields["t_ns"] / 1e9, m.fields["pixels"])
                                                 for k, m in enumerate(msgs[a:b], start=a)),
                                   6, BOARD, n_workers=1, restart_every=3)  # fmt: skip
    assert len(got) and got.equals(ref)
    assert got["t_s"].iloc[0] == T0 / 1e9


@pytest.mark.parametrize("storage", ["ros1", "sqlite3", "mcap"])
def test_streaming_memory_is_flat(tmp_path, storage):
    """Peak traced memory reading a 31 MB topic stays that of a few frames and one read unit."""
    frame = rng.integers(0, 256, (240, 320), dtype=np.uint8)  # 77 kB
    peaks = {}
    for n in (40, 400):
        bag = write_bag(tmp_path / f"s{n}", storage, [_img(i, "mono8", frame) for i in range(n)])
        tracemalloc.start()
        count = sum(1 for _ in iter_bag_gray(bag, "/cam/image_raw"))
        peaks[n] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        assert count == n
    assert peaks[400] < 8e6 and peaks[400] < 2.0 * peaks[40] + 2e6, peaks
