"""Calibration stills and video frames."""

from __future__ import annotations

import logging
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def list_stills(folder) -> list[Path]:
    """Image files of a calibration folder, sorted by name.

    Parameters
    ----------
    folder : str or Path
        The calibration folder (``calib_dir``).

    Returns
    -------
    list of Path
        Files with a suffix in :data:`IMAGE_SUFFIXES` (any case), sorted; may be empty.

    Raises
    ------
    InputError
        ``folder`` is a file or does not exist.
    """
    folder = Path(folder)
    if folder.is_file():
        raise InputError(f"{folder}: is a file, expected a folder of stills (calib_dir)")
    if not folder.is_dir():
        raise InputError(f"{folder}: calibration folder not found")
    return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _truncated(path) -> str | None:
    """Pillow's complaint when the image's data ends early (OpenCV decodes a cut JPEG in silence,
    grey below the cut), or None."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            im.load()
    except OSError as exc:  # Pillow's UnidentifiedImageError is one too: cv2 may read those
        return str(exc) if "truncated" in str(exc) else None
    return None


def read_gray(path) -> np.ndarray:
    """An image as 8-bit grayscale; an empty, cut or unreadable file is an InputError naming it.

    Parameters
    ----------
    path : str or Path
        The image file.

    Returns
    -------
    ndarray of uint8, shape (H, W)

    Raises
    ------
    InputError
        ``{path}: empty file (0 bytes)``, ``{path}: cannot be decoded (truncated? ...)`` (its
        data ends early: a copy or upload cut off) or ``{path}: cannot be decoded as an image``.
    """
    path = Path(path)
    if path.is_file() and path.stat().st_size == 0:
        raise InputError(f"{path}: empty file (0 bytes), cannot be decoded as an image")
    cut = _truncated(path) if path.is_file() else None
    if cut is not None:
        raise InputError(f"{path}: cannot be decoded (truncated? {cut})")
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"{path}: cannot be decoded as an image")
    return img


def read_stills(paths) -> tuple[list[tuple[str, np.ndarray]], list[tuple[str, str]]]:
    """Calibration stills as 8-bit grayscale; those that cannot be decoded are named, not read.

    Parameters
    ----------
    paths : sequence of Path
        The stills (:func:`list_stills`).

    Returns
    -------
    images : list of (str, ndarray)
        ``(file name, gray (H, W) uint8)`` of the stills that decode, in the order given.
    unreadable : list of (str, str)
        ``(file name, reason)`` of the others (empty, truncated, not an image: see
        :func:`read_gray`), each also logged at WARNING. The calibration lists them unused
        with their reason.
    """
    images, unreadable = [], []
    for p in paths:
        try:
            images.append((p.name, read_gray(p)))
        except InputError as exc:
            reason = str(exc).removeprefix(f"{p}: ")
            log.warning("%s: %s; left out", p, reason)
            unreadable.append((p.name, reason))
    return images, unreadable


def _check_video_path(path) -> Path:
    """``path`` as a Path, or an InputError when it is a folder or does not exist."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a video file (video)")
    if not path.is_file():
        raise InputError(f"{path}: video file not found")
    return path


# A PTS gap longer than this many median frame periods counts as dropped frames.
DROP_GAP_PERIODS = 1.5


def _open_av(path):
    """``av.open`` of a video file, or an InputError naming it."""
    import av

    path = _check_video_path(path)
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        hint = ""
        if path.suffix.lower() in (".mp4", ".mov", ".m4v") and path.stat().st_size > 0:
            # a recording cut off (battery, crash) before the camera wrote the index at its end
            hint = ("; an MP4/MOV whose recording was cut off has no index (moov) and cannot be "
                    "read as it is: re-export it, or rebuild the index from a good recording "
                    "of the same camera")
        raise InputError(f"{path}: cannot be opened as a video ({exc}){hint}") from exc
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: no video stream (expected a video file)")
    return container


def video_timing(path) -> dict:
    """Frame count and times of a video from its packets (demuxed, not decoded).

    Parameters
    ----------
    path : str or Path

    Returns
    -------
    timing : dict
        ``n_frames_header`` (the container's stated count, 0 when it states none),
        ``n_frames`` (video packets with a timestamp: the frames that can decode),
        ``t_s`` (ndarray (n_frames,), presentation times in order, s from the stream start),
        ``period_s`` (median frame period, s), ``n_dropped`` (frames missing in PTS gaps
        longer than ``DROP_GAP_PERIODS`` median periods), ``gaps`` (list of
        ``[after_frame, missing]``), ``codec`` (FFmpeg's name of the stream's codec),
        ``n_key_frames`` (packets flagged key frames: all of them in an intra-only video,
        MJPEG say; few in a motion-compensated one, which codes most frames from the last),
        ``inter_coded`` (fewer key frames than frames: some frame is coded from another).

    Raises
    ------
    InputError
        Not a file, not a video, or a video without frames.
    """
    import av

    container = _open_av(path)
    try:
        stream = container.streams.video[0]
        n_header = int(stream.frames or 0)
        tb = float(stream.time_base)
        t0 = stream.start_time
        codec = str(stream.codec_context.name)
        pts = []
        n_untimed = 0
        n_key = 0
        try:
            for packet in container.demux(stream):
                if packet.size and packet.pts is not None:
                    pts.append(packet.pts)
                    n_key += bool(packet.is_keyframe)
                n_untimed += bool(packet.size) and packet.pts is None
        except av.error.FFmpegError as exc:  # a truncated file: keep what demuxed
            log.warning("%s: demuxing stopped after %d packets (%s)", path, len(pts), exc)
    finally:
        container.close()
    if not pts:
        if n_untimed:
            raise _untimed_error(path, n_untimed)
        raise InputError(f"{path}: video has no frames (header states {n_header})")
    pts = np.sort(np.asarray(pts, dtype=np.int64))
    origin = pts[0] if t0 is None else t0
    t_s = (pts - origin) * tb
    dt = np.diff(t_s)
    period = float(np.median(dt)) if len(dt) else 0.0
    gaps = []
    if period > 0:
        for i in np.flatnonzero(dt > DROP_GAP_PERIODS * period):
            gaps.append([int(i), int(round(dt[i] / period)) - 1])
    if n_header and n_header != len(pts):
        log.warning("%s: the header states %d frames, %d demux (the count used)", path,
                    n_header, len(pts))
    if gaps:
        log.warning("%s: %d dropped frames in %d timestamp gaps over %.1f median periods "
                    "(first after frame %d)", path, sum(g[1] for g in gaps), len(gaps),
                    DROP_GAP_PERIODS, gaps[0][0])
    return {
        "n_frames_header": n_header,
        "n_frames": len(pts),
        "t_s": t_s,
        "period_s": period,
        "n_dropped": int(sum(g[1] for g in gaps)),
        "gaps": gaps,
        "codec": codec,
        "n_key_frames": int(n_key),
        "inter_coded": n_key < len(pts),
    }


def _untimed_error(path, n_packets) -> InputError:
    """The error for a video whose frames carry no timestamps (a raw H.264 / HEVC stream)."""
    return InputError(
        f"{path}: its {n_packets} frames carry no timestamps (a raw H.264/HEVC stream, as "
        "Raspberry Pi cameras record): give them times in an MP4 with `cvsflow remux "
        f"{Path(path).name} --timestamps <the camera's --save-pts file> --out video.mp4`, or "
        "`--fps <the camera's frame rate>`, and use that video")


def video_size(path) -> dict:
    """Size of a video's frames as :func:`iter_video_gray` yields them (display rotation applied).

    Parameters
    ----------
    path : str or Path
        The video file.

    Returns
    -------
    dict
        ``width``, ``height`` (px, upright), ``rotation_deg`` (the display rotation, 0 when
        none), ``stored_width``, ``stored_height`` (px, as encoded).

    Raises
    ------
    InputError
        Not a readable video, or a stream without a frame size.
    """
    import av

    container = _open_av(path)
    rotation = 0.0
    try:
        stream = container.streams.video[0]
        width, height = int(stream.codec_context.width), int(stream.codec_context.height)
        try:
            frame = next(container.decode(stream), None)
        except av.error.FFmpegError as exc:  # a broken first packet: the size is the header's
            log.warning("%s: first frame does not decode (%s); display rotation taken as 0", path, exc)
            frame = None
        if frame is not None:
            rotation = float(frame.rotation or 0.0)
            width, height = int(frame.width), int(frame.height)
    finally:
        container.close()
    if width <= 0 or height <= 0:
        raise InputError(f"{path}: video has no frame size")
    turns = display_turns(rotation, path)
    w, h = (height, width) if turns % 2 else (width, height)
    return {"width": w, "height": h, "rotation_deg": 90.0 * turns, "stored_width": width,
            "stored_height": height}  # fmt: skip


def video_info(path) -> dict:
    """Frame count, rate (Hz) and size of a video.

    ``n_frames`` is the number of frames that demux (``video_timing``), not the header's
    count (``n_frames_header``), which a truncated or variable-rate file may get wrong;
    ``fps`` is 1 / the median frame period.

    Parameters
    ----------
    path : str or Path
        The video file.

    Returns
    -------
    dict
        ``n_frames`` (demuxed), ``n_frames_header``, ``n_dropped`` (frames missing from the
        timestamp gaps), ``fps`` (Hz; the stream's average rate when the period is unknown),
        and :func:`video_size`'s keys.

    Raises
    ------
    InputError
        Not a readable video, or a stream without a frame size.
    """
    timing = video_timing(path)
    size = video_size(path)
    container = _open_av(path)
    try:
        rate = float(container.streams.video[0].average_rate or 0.0)
    finally:
        container.close()
    fps = 1.0 / timing["period_s"] if timing["period_s"] > 0 else rate
    return {
        "n_frames": timing["n_frames"],
        "n_frames_header": timing["n_frames_header"],
        "n_dropped": timing["n_dropped"],
        "fps": fps,
        **size,
    }


def iter_video_gray(path, start=0, stop=None, undecodable=False
                    ) -> Iterator[tuple[int, float, np.ndarray | None]]:
    """Yield (frame index, time in s from the container, grayscale image) for frames [start, stop).

    Decoded with PyAV, packet by packet. Frame k is the k-th frame in presentation order; its
    time is its presentation timestamp (pts * time_base) from the stream's start, so variable
    frame rate and dropped frames show in the times, not in the indices. ``start`` > 0 seeks
    to the key frame before it and decodes up to it: exact, whatever the codec. A frame with a
    display rotation (a phone held upright stores its frames on their side) is turned upright,
    as players show it and as ``cv2.imread`` turns a still by its EXIF orientation.

    A packet the decoder refuses (a damaged recording: a bad card sector, a cut-off upload)
    costs its frame, not the rest of the video: decoding goes on with the next packet, as the
    ``ffmpeg`` tool does, and the frame keeps its index (from the packets' timestamps), so a
    chunk read from ``start`` > 0 numbers frames as a whole pass does.

    Parameters
    ----------
    path : str or Path
        The video file.
    start : int, default 0
        First frame index (presentation order) to yield.
    stop : int, optional
        Frame index to stop before; default the end of the stream.
    undecodable : bool, default False
        Also yield the frames that could not be decoded, as ``(frame, t_s, None)``; False
        leaves them out (their indices are then missing). Either way they are counted in one
        WARNING naming the file.

    Returns
    -------
    iterator of (int, float, ndarray or None)
        ``(frame, t_s, gray)``: frame index, PTS time in s from the stream start, and the
        8-bit grey image of shape (H, W) (None for an undecodable frame, with
        ``undecodable``). Nothing when ``start`` is past the last frame.

    Raises
    ------
    InputError
        Not a file or not a video, or a video of which not one frame decodes.
    """
    import av

    start = int(start)
    all_pts = _packet_pts(path) if start > 0 else None
    if all_pts is not None and start >= len(all_pts):
        return
    container = _open_av(path)
    state = {"next": start, "failed": 0, "decoded": 0, "missing": 0, "first_error": None}
    try:
        stream = container.streams.video[0]
        tb = float(stream.time_base)
        t0 = stream.start_time
        if all_pts is not None:
            container.seek(int(all_pts[start]), stream=stream, backward=True, any_frame=False)

        def frames():
            for packet in container.demux(stream):
                try:
                    yield from packet.decode()
                except av.error.FFmpegError as exc:
                    state["failed"] += 1
                    state["first_error"] = state["first_error"] or (state["next"], str(exc))

        def gap(until):
            """Frames [state["next"], until) that did not decode: counted, yielded as None."""
            for missing in range(state["next"], until):
                state["missing"] += 1
                if undecodable:
                    yield missing, float((all_pts[missing] - origin) * tb), None

        origin = None
        n_untimed = 0
        for frame in frames():
            if frame.pts is None:
                n_untimed += 1
                continue
            if origin is None:
                origin = t0 if t0 is not None else (all_pts[0] if all_pts is not None else frame.pts)
            if state["failed"] and all_pts is None:
                # from the first refused packet on, frames are numbered by their timestamps
                all_pts = _packet_pts(path)
            if all_pts is not None:
                index = int(np.searchsorted(all_pts, frame.pts))
                if index < start:
                    continue
            else:
                index = state["next"]
            if stop is not None and index >= stop:
                break
            yield from gap(index)
            state["next"] = index + 1
            state["decoded"] += 1
            yield index, float((frame.pts - origin) * tb), _gray(frame, display_turns(frame.rotation, path))
        if n_untimed and state["decoded"] == 0:
            raise _untimed_error(path, n_untimed)
        if state["failed"] and state["decoded"] == 0 and start == 0:
            raise InputError(f"{path}: not one frame decodes ({state['failed']} packets refused, "
                             f"the first: {state['first_error'][1]})")
        if state["failed"]:
            if all_pts is None:
                all_pts = _packet_pts(path)
            end = len(all_pts) if stop is None else min(stop, len(all_pts))
            if origin is None:
                origin = t0 if t0 is not None else all_pts[0]
            yield from gap(end)
            state["next"] = max(state["next"], end)
    finally:
        container.close()
        if state["failed"]:
            log.warning("%s: %d packets could not be decoded (the first before frame %s: %s); "
                        "%d frames of [%d, %s) are undecodable", path, state["failed"],
                        state["first_error"][0], state["first_error"][1], state["missing"],
                        start, "end" if stop is None else stop)  # fmt: skip


# Planar YUV formats whose first plane is the luma: read directly (2.6x faster at 720p than
# swscale's conversion to gray8, measured 662 vs 257 frames/s), limited range expanded to
# 0..255 as a colour conversion would.
_LUMA_FORMATS = {"yuv420p", "yuvj420p", "yuv422p", "yuvj422p", "yuv444p", "yuvj444p", "nv12",
                 "nv21", "yuv420p10le", "gray"}
_LIMITED_TO_FULL = np.clip(np.rint((np.arange(256) - 16.0) * 255.0 / 219.0), 0, 255).astype(
    np.uint8
)


def display_turns(rotation_deg, path="video") -> int:
    """Quarter turns (counter-clockwise, ``np.rot90``'s k) that show a stored frame upright.

    Parameters
    ----------
    rotation_deg : float
        The stream's display rotation (PyAV ``VideoFrame.rotation``: the display matrix's
        counter-clockwise angle, as FFmpeg and OpenCV's auto-orientation apply it).
    path : str or Path
        Named in the warning for an angle that is not a multiple of 90 degrees.

    Returns
    -------
    int
        0, 1, 2 or 3.
    """
    k = int(round(float(rotation_deg) / 90.0))
    if abs(float(rotation_deg) - 90.0 * k) > 1.0:
        log.warning("%s: display rotation %.1f deg is not a multiple of 90; frames are read as stored",
                    path, rotation_deg)  # fmt: skip
        return 0
    return k % 4


def _gray(frame, turns=0) -> np.ndarray:
    """8-bit grey image (H, W) of a decoded PyAV frame (a copy: the decoder reuses buffers),
    turned by ``turns`` quarter turns counter-clockwise."""
    name = frame.format.name
    if name not in _LUMA_FORMATS or name.endswith("10le"):
        y = frame.to_ndarray(format="gray")
    else:
        plane = frame.planes[0]
        y = np.frombuffer(plane, np.uint8).reshape(-1, plane.line_size)[: frame.height, : frame.width]
        full = name.startswith("yuvj") or name == "gray" or getattr(frame, "color_range", 0) == 2
        y = np.array(y) if full else cv2.LUT(y, _LIMITED_TO_FULL)
    return np.ascontiguousarray(np.rot90(y, turns) if turns else y)


def _packet_pts(path) -> np.ndarray:
    """Sorted presentation timestamps (stream time base) of a video's packets."""
    container = _open_av(path)
    try:
        stream = container.streams.video[0]
        pts = [p.pts for p in container.demux(stream) if p.size and p.pts is not None]
    finally:
        container.close()
    return np.sort(np.asarray(pts, dtype=np.int64))
