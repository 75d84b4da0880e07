"""An image topic of a ROS bag as a camera input: the frame source of a frame folder or a video.

:func:`iter_bag_gray` yields ``(frame, t_s, gray)`` as :func:`cvsflow.io.frames.iter_frames_gray`
and :func:`cvsflow.io.media.iter_video_gray` do, so the corners stage runs on a bag unchanged
(``functools.partial(iter_bag_gray, bag, topic)`` is a frame source of
:func:`cvsflow.corners.extract_corners_parallel`); :func:`bag_frame_list` is the frame list with
the exact ``t_ns`` (for :func:`cvsflow.io.frames.add_frame_ns`), :func:`bag_frames_info` the
count, rate and size. Frame k is the k-th message of the topic in the bag; its time is the
message's header stamp (exact int64 ns; ``t_s = t_ns / 1e9`` as a frame folder's), or the bag's
receive time with ``time="receive"``.

Pixels:

- ``sensor_msgs/CompressedImage``: the message's bytes (the camera's JPEG or PNG) decoded once by
  ``cv2.imdecode`` with the flag ``cv2.imread`` uses, never re-encoded: a frame equals
  ``cv2.imread`` of the same bytes in a file (a JPEG decoded straight to grey differs from one
  decoded to colour and converted). The format is found from the bytes, whatever ``format`` says.
- ``sensor_msgs/Image``: the payload viewed in place honouring ``step`` (padded rows) and
  ``is_bigendian``, converted as :data:`RAW_ENCODINGS` says (16 bits to 8 by ``round(x / 257)``).

Bad input: an encoding OpenCV cannot decode (``32FC1`` depth as a camera frame, ``nv12``, a
``compressedDepth`` or H.264 ``CompressedImage``) is an :class:`~cvsflow.exceptions.ImageDecodeError`
naming the topic, the message index and the encoding. A single damaged frame (JPEG or PNG data
cut short or refused by the decoder, raw data shorter than ``step`` x ``height``) costs that
frame, as in a frame folder: named in a WARNING and yielded as None (``undecodable=True``) or left
out; not one frame decoding is an error. Header stamps of zero are a
:class:`~cvsflow.exceptions.ZeroStampError` (read with ``time="receive"``); stamps that go back
or repeat are a :class:`~cvsflow.exceptions.BagError` naming both messages.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Iterator

import cv2
import numpy as np
import pandas as pd

from cvsflow.exceptions import BagError, DamagedFrameError, ImageDecodeError
from cvsflow.io.frames import data_is_complete
from cvsflow.io.rosbag import COMPRESSED_IMAGE, IMAGE_TYPES, open_bag

log = logging.getLogger(__name__)

MODES = ("gray", "bgr", "unchanged")
#: Raw ``sensor_msgs/Image`` encodings: dtype, channels, the cv2 code to grey, to BGR (None: it is
#: already). OpenCV names Bayer patterns by the second row: ROS ``bayer_rggb`` is OpenCV's
#: ``BayerBG`` (as cv_bridge maps it).
RAW_ENCODINGS = {
    "mono8": ("uint8", 1, None, cv2.COLOR_GRAY2BGR),
    "8UC1": ("uint8", 1, None, cv2.COLOR_GRAY2BGR),
    "mono16": ("uint16", 1, None, cv2.COLOR_GRAY2BGR),
    "16UC1": ("uint16", 1, None, cv2.COLOR_GRAY2BGR),
    "bgr8": ("uint8", 3, cv2.COLOR_BGR2GRAY, None),
    "8UC3": ("uint8", 3, cv2.COLOR_BGR2GRAY, None),
    "rgb8": ("uint8", 3, cv2.COLOR_RGB2GRAY, cv2.COLOR_RGB2BGR),
    "bgra8": ("uint8", 4, cv2.COLOR_BGRA2GRAY, cv2.COLOR_BGRA2BGR),
    "8UC4": ("uint8", 4, cv2.COLOR_BGRA2GRAY, cv2.COLOR_BGRA2BGR),
    "rgba8": ("uint8", 4, cv2.COLOR_RGBA2GRAY, cv2.COLOR_RGBA2BGR),
    "bgr16": ("uint16", 3, cv2.COLOR_BGR2GRAY, None),
    "rgb16": ("uint16", 3, cv2.COLOR_RGB2GRAY, cv2.COLOR_RGB2BGR),
    "bgra16": ("uint16", 4, cv2.COLOR_BGRA2GRAY, cv2.COLOR_BGRA2BGR),
    "rgba16": ("uint16", 4, cv2.COLOR_RGBA2GRAY, cv2.COLOR_RGBA2BGR),
    "bayer_rggb8": ("uint8", 1, cv2.COLOR_BayerBG2GRAY, cv2.COLOR_BayerBG2BGR),
    "bayer_bggr8": ("uint8", 1, cv2.COLOR_BayerRG2GRAY, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg8": ("uint8", 1, cv2.COLOR_BayerGR2GRAY, cv2.COLOR_BayerGR2BGR),
    "bayer_grbg8": ("uint8", 1, cv2.COLOR_BayerGB2GRAY, cv2.COLOR_BayerGB2BGR),
    "bayer_rggb16": ("uint16", 1, cv2.COLOR_BayerBG2GRAY, cv2.COLOR_BayerBG2BGR),
    "bayer_bggr16": ("uint16", 1, cv2.COLOR_BayerRG2GRAY, cv2.COLOR_BayerRG2BGR),
    "bayer_gbrg16": ("uint16", 1, cv2.COLOR_BayerGR2GRAY, cv2.COLOR_BayerGR2BGR),
    "bayer_grbg16": ("uint16", 1, cv2.COLOR_BayerGB2GRAY, cv2.COLOR_BayerGB2BGR),
    "uyvy": ("uint8", 2, cv2.COLOR_YUV2GRAY_UYVY, cv2.COLOR_YUV2BGR_UYVY),
    "yuv422": ("uint8", 2, cv2.COLOR_YUV2GRAY_UYVY, cv2.COLOR_YUV2BGR_UYVY),
    "yuyv": ("uint8", 2, cv2.COLOR_YUV2GRAY_YUY2, cv2.COLOR_YUV2BGR_YUY2),
    "yuv422_yuy2": ("uint8", 2, cv2.COLOR_YUV2GRAY_YUY2, cv2.COLOR_YUV2BGR_YUY2),
}
_GENERIC = re.compile(r"(8U|8S|16U|16S|32S|32F|64F)C([1-9])")
_GENERIC_DTYPE = {"8U": "uint8", "8S": "int8", "16U": "uint16", "16S": "int16", "32S": "int32",
                  "32F": "float32", "64F": "float64"}  # fmt: skip
_IMREAD = {"gray": cv2.IMREAD_GRAYSCALE, "bgr": cv2.IMREAD_COLOR, "unchanged": cv2.IMREAD_UNCHANGED}
#: Leading bytes of the encoded formats OpenCV decodes (the kind decides the completeness check).
_MAGIC = ((b"\xff\xd8\xff", "jpeg"), (b"\x89PNG\r\n\x1a\n", "png"), (b"BM", "bmp"), (b"II*\x00", "tiff"),
          (b"MM\x00*", "tiff"), (b"RIFF", "webp"))  # fmt: skip


def _decode_error(where: str, topic: str, index: int, encoding: str, why: str,
                  cls=ImageDecodeError) -> ImageDecodeError:  # fmt: skip
    return cls(f"{where}: topic {topic}, message {index}: encoding {encoding!r}: {why}", topic=topic,
               index=index, encoding=encoding, reason=why)  # fmt: skip


def decode_raw_image(msg, mode: str = "gray", *, where: str = "", topic: str = "",
                     index: int = -1) -> np.ndarray:  # fmt: skip
    """Pixels of a ``sensor_msgs/Image`` message.

    Parameters
    ----------
    msg : sensor_msgs/msg/Image
        As ``rosbags`` deserialises it: ``height``, ``width``, ``encoding``, ``is_bigendian``,
        ``step`` (bytes a row, more than the pixels' when rows are padded), ``data`` (uint8).
    mode : {"gray", "bgr", "unchanged"}
        ``gray``: uint8 (H, W); ``bgr``: uint8 (H, W, 3), 16-bit data as ``round(x / 257)``;
        ``unchanged``: the message's own pixels in its dtype (native byte order), also for the
        generic ``8UC1`` .. ``64FC4`` encodings.
    where, topic, index : optional
        The bag, the topic and the message index, named in errors.

    Returns
    -------
    ndarray
        A new, writable array.

    Raises
    ------
    ImageDecodeError
        An encoding without a conversion to ``mode`` (``32FC1`` to gray, ``nv12``, ...).
    DamagedFrameError
        ``data`` shorter than ``step`` x ``height``, or ``step`` shorter than a row.
    """
    enc = msg.encoding
    if enc in RAW_ENCODINGS:
        dtype, nch, to_gray, to_bgr = RAW_ENCODINGS[enc]
    elif (m := _GENERIC.fullmatch(enc)) and mode == "unchanged":
        dtype, nch, to_gray, to_bgr = _GENERIC_DTYPE[m.group(1)], int(m.group(2)), None, None
    else:
        raise _decode_error(where, topic, index, enc, f"OpenCV has no conversion of it to {mode!r} (raw "
                            f"encodings read: {', '.join(RAW_ENCODINGS)})")  # fmt: skip
    dt = np.dtype(dtype).newbyteorder(">" if msg.is_bigendian else "<")
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    row_bytes = w * nch * dt.itemsize
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if step < row_bytes or data.size < step * h:
        why = (f"{data.size} data bytes, step {step} for {h} rows of {w} pixels ({row_bytes} bytes a row): "
               "the message is cut short or its step is wrong")
        raise _decode_error(where, topic, index, enc, why, DamagedFrameError)
    rows = data[: step * h].reshape(h, step)[:, :row_bytes]
    img = np.ascontiguousarray(rows).view(dt).reshape((h, w) if nch == 1 else (h, w, nch))
    img = img.astype(dt.newbyteorder("="), copy=False)
    if mode != "unchanged":
        code = to_gray if mode == "gray" else to_bgr
        img = cv2.cvtColor(img, code) if code is not None else img
        if img.dtype == np.uint16:
            img = cv2.convertScaleAbs(img, alpha=1.0 / 257.0)
    if np.shares_memory(img, data) or not img.flags.writeable:
        img = img.copy()
    return img


def decode_compressed_image(msg, mode: str = "gray", *, where: str = "", topic: str = "",
                            index: int = -1) -> np.ndarray:  # fmt: skip
    """Pixels of a ``sensor_msgs/CompressedImage`` (its JPEG, PNG, ... bytes decoded once).

    Parameters
    ----------
    msg : sensor_msgs/msg/CompressedImage
        ``format`` (``jpeg``, ``png``, ``rgb8; jpeg compressed bgr8``, ...) and ``data``.
    mode : {"gray", "bgr", "unchanged"}
        Decoded with the flag ``cv2.imread`` uses for it (``IMREAD_GRAYSCALE``, ``IMREAD_COLOR``,
        ``IMREAD_UNCHANGED``): ``gray`` equals :func:`cvsflow.io.frames.read_frame_gray` of the
        same bytes in a file.
    where, topic, index : optional
        Named in errors.

    Returns
    -------
    ndarray
        uint8 (H, W) for ``gray``, uint8 (H, W, 3) for ``bgr``.

    Raises
    ------
    ImageDecodeError
        Bytes of no format OpenCV decodes (an H.264 or ``compressedDepth`` image; the first
        bytes are shown).
    DamagedFrameError
        JPEG or PNG data cut short (no end marker) or refused by the decoder.
    """
    fmt = str(msg.format)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    head = bytes(data[:8])
    kind = next((k for magic, k in _MAGIC if head.startswith(magic)), None)
    if kind is None or "compresseddepth" in fmt.replace(" ", "").lower():
        why = ("a compressedDepth image (a depth map behind a 12-byte header), not a camera frame"
               if "compresseddepth" in fmt.replace(" ", "").lower() else
               f"{data.size} bytes of no format OpenCV decodes (first bytes {head.hex(' ') or 'none'}; "
               "a JPEG starts ff d8 ff, a PNG 89 50 4e 47)")  # fmt: skip
        raise _decode_error(where, topic, index, fmt, why)
    if kind in ("jpeg", "png") and not data_is_complete(bytes(data[-4096:]), kind):
        why = f"{kind.upper()} data of {data.size} bytes without its end marker (cut short)"
        raise _decode_error(where, topic, index, fmt, why, DamagedFrameError)
    img = cv2.imdecode(data, _IMREAD[mode])
    if img is None:
        why = f"OpenCV refuses these {data.size} bytes of {kind.upper()} data"
        raise _decode_error(where, topic, index, fmt, why, DamagedFrameError)
    return img


def _decoder(msgtype: str, mode: str):
    if mode not in MODES:
        raise ValueError(f"mode={mode!r}; expected one of {', '.join(MODES)}")
    return decode_compressed_image if msgtype == COMPRESSED_IMAGE else decode_raw_image


def iter_bag_images(bag, topic: str, mode: str = "gray", time: str = "header", start: int = 0,
                    stop: int | None = None, undecodable: bool = False
                    ) -> Iterator[tuple[int, int, np.ndarray | None]]:  # fmt: skip
    """Yield ``(frame, t_ns, image)`` for the messages ``[start, stop)`` of an image topic.

    Parameters
    ----------
    bag : str, Path or list of them
        As :func:`cvsflow.io.rosbag.bag_paths`.
    topic : str
        A ``sensor_msgs/Image`` or ``sensor_msgs/CompressedImage`` topic (leading ``/`` optional).
    mode : {"gray", "bgr", "unchanged"}
        See :func:`decode_raw_image` and :func:`decode_compressed_image`.
    time : {"header", "receive"}
        ``t_ns`` from the header stamp (exact; zero is a ZeroStampError) or the receive time.
    start, stop : int
        Message indices; the messages before ``start`` are skipped undecoded.
    undecodable : bool
        Also yield damaged frames as ``(frame, t_ns, None)``; False leaves them out. Either way
        they are named in one WARNING.

    Returns
    -------
    iterator of (int, int, ndarray or None)

    Raises
    ------
    TopicNotFoundError, TopicTypeError
        No such topic (the bag's topics listed), or not an image topic.
    ImageDecodeError
        An encoding OpenCV cannot decode (topic, message index, encoding named); or not one
        frame of the whole topic decodes.
    ZeroStampError, BagError
        A zero header stamp; header stamps that go back or repeat (both messages named).
    """
    with open_bag(bag) as b:
        name, info = b.topic(topic, IMAGE_TYPES, "an image topic (sensor_msgs Image or CompressedImage)")
        decode = _decoder(info.msgtype, mode)
        bad: list[str] = []
        n_ok, prev = 0, None
        try:
            for index, t_ns, _t_rx, msg in b.messages(name, time, start, stop):
                prev = _check_order(b.label, name, prev, index, t_ns)
                try:
                    img = decode(msg, mode, where=b.label, topic=name, index=index)
                except DamagedFrameError as exc:
                    bad.append(f"message {index} ({exc.reason})")
                    if undecodable:
                        yield index, t_ns, None
                    continue
                n_ok += 1
                yield index, t_ns, img
        finally:
            if bad:
                log.warning("%s: topic %s: %d frames cannot be decoded, left out: %s", b.label, name,
                            len(bad), "; ".join(bad[:5]) + (" ..." if len(bad) > 5 else ""))  # fmt: skip
        if bad and n_ok == 0 and start == 0 and stop is None:
            raise ImageDecodeError(f"{b.label}: topic {name}: not one of its {len(bad)} frames decodes "
                                   f"(the first: {bad[0]})", topic=name, index=0)  # fmt: skip


def _check_order(label, topic, prev, index, t_ns):
    """(index, t_ns) of this frame, after checking its time is later than the one before."""
    if prev is not None and t_ns <= prev[1]:
        what = "repeats" if t_ns == prev[1] else "goes back from"
        raise BagError(f"{label}: topic {topic}, message {index}: its time {t_ns} ns {what} message "
                       f"{prev[0]}'s {prev[1]} ns; expected frame times that increase (read the "
                       "receive times with time: receive if the header stamps are not the capture "
                       "order)")  # fmt: skip
    return index, t_ns


def iter_bag_gray(bag, topic: str, start: int = 0, stop: int | None = None, undecodable: bool = False,
                  time: str = "header") -> Iterator[tuple[int, float, np.ndarray | None]]:  # fmt: skip
    """Yield ``(frame, t_s, gray)`` for the frames ``[start, stop)`` of a bag's image topic.

    The frame source interface of :func:`cvsflow.io.frames.iter_frames_gray`: frame k is the
    topic's k-th message, ``t_s`` its time (``t_ns / 1e9``, absolute seconds, as a frame
    folder's).

    Parameters
    ----------
    bag : str, Path or list of them
        As :func:`cvsflow.io.rosbag.bag_paths`.
    topic : str
        The image topic.
    start : int
        First frame index.
    stop : int, optional
        Index to stop before; default the last frame.
    undecodable : bool
        Also yield damaged frames as ``(frame, t_s, None)``.
    time : {"header", "receive"}
        Header stamps (default) or the bag's receive times.

    Returns
    -------
    iterator of (int, float, ndarray or None)

    Raises
    ------
    TopicNotFoundError, TopicTypeError, ImageDecodeError, ZeroStampError, BagError
        As :func:`iter_bag_images`.
    """
    for frame, t_ns, gray in iter_bag_images(bag, topic, "gray", time, start, stop, undecodable):
        # float(t_ns) / 1e9, as numpy divides a frame folder's int64 times
        yield frame, float(t_ns) / 1e9, gray


def bag_frame_list(bag, topic: str, time: str = "header") -> pd.DataFrame:
    """The frames of a bag's image topic with their exact times, without decoding a pixel.

    Parameters
    ----------
    bag, topic, time
        As :func:`iter_bag_gray`.

    Returns
    -------
    frames : DataFrame
        ``frame`` (int64, the message index), ``t_ns`` (int64, per ``time``), ``t_s``
        (``t_ns / 1e9``), ``t_receive_ns`` (int64) and ``encoding`` (the raw encoding or the
        compressed format); ``attrs``: ``bag``, ``topic``, ``msgtype``, ``storage``, ``time``.

    Raises
    ------
    TopicNotFoundError, TopicTypeError, ZeroStampError, BagError
        As :func:`iter_bag_images`; a topic without messages.
    """
    rows = []
    with open_bag(bag) as b:
        name, info = b.topic(topic, IMAGE_TYPES, "an image topic (sensor_msgs Image or CompressedImage)")
        prev = None
        for index, t_ns, t_rx, msg in b.messages(name, time):
            prev = _check_order(b.label, name, prev, index, t_ns)
            rows.append((index, t_ns, t_rx, msg.format if info.msgtype == COMPRESSED_IMAGE else msg.encoding))
        if not rows:
            raise BagError(f"{b.label}: topic {name} has no messages")
        attrs = {"bag": b.label, "topic": name, "msgtype": info.msgtype, "storage": b.storage, "time": time}
    t = np.array([r[1] for r in rows], np.int64)
    out = pd.DataFrame({"frame": np.array([r[0] for r in rows], np.int64), "t_ns": t, "t_s": t / 1e9,
                        "t_receive_ns": np.array([r[2] for r in rows], np.int64),
                        "encoding": [r[3] for r in rows]})  # fmt: skip
    out.attrs = attrs
    return out


def bag_frames_info(bag, topic: str, time: str = "header") -> dict:
    """Frame count, rate and size of a bag's image topic (as :func:`cvsflow.io.frames.frame_folder_info`).

    Parameters
    ----------
    bag, topic, time
        As :func:`iter_bag_gray`.

    Returns
    -------
    dict
        ``n_frames``, ``fps`` (1 / the median interval, Hz; 0 for one frame), ``period_s``,
        ``width``, ``height`` (px, of the first frame that decodes), ``t0_ns``, ``t1_ns``,
        ``layout`` (``rosbag``), ``storage``, ``topic``, ``encoding`` (the first message's).

    Raises
    ------
    TopicNotFoundError, TopicTypeError, ImageDecodeError, ZeroStampError, BagError
        As :func:`bag_frame_list`; or no frame decodes.
    """
    frames = bag_frame_list(bag, topic, time)
    t = frames["t_ns"].to_numpy(np.int64)
    period = float(np.median(np.diff(t))) / 1e9 if len(t) > 1 else 0.0
    gray = next((g for _f, _t, g in iter_bag_images(bag, topic, "gray", time)), None)
    return {"n_frames": len(frames), "fps": 1.0 / period if period > 0 else 0.0, "period_s": period,
            "width": int(gray.shape[1]), "height": int(gray.shape[0]), "t0_ns": int(t[0]),
            "t1_ns": int(t[-1]),
            "layout": "rosbag", "storage": frames.attrs["storage"], "topic": frames.attrs["topic"],
            "encoding": str(frames["encoding"].iloc[0])}  # fmt: skip
