"""Raw H.264 / HEVC streams (no container, no timestamps) given frame times in an MP4.

A Raspberry Pi camera (``raspivid``, ``libcamera-vid``, ``rpicam-vid``) and many embedded
encoders write a bare Annex B stream: its packets carry no presentation times, so nothing
downstream can tell the frame rate, a dropped frame or a variable rate. The camera's own
timestamps, where it saved them (``--save-pts``: mkvmerge's "timecode format v2", one time
in ms per frame), or else its nominal frame rate, are written into an MP4 beside it, the
packets copied as they are (no re-encoding). The pipeline then reads the MP4 as any other
video.
"""

from __future__ import annotations

import contextlib
import fractions
import logging
from pathlib import Path

import numpy as np

from cvsflow.exceptions import InputError
from cvsflow.geometry import sample_period

log = logging.getLogger(__name__)

#: Time base of the MP4 written, s per tick: fine enough that a timecode in microseconds
#: (libcamera's) is kept to 11 us, far below any frame-time question here.
MP4_TIME_BASE = fractions.Fraction(1, 90000)


def read_timecodes_v2(path) -> np.ndarray:
    """Frame times of a "timecode format v2" file (``libcamera-vid --save-pts``, mkvmerge).

    Parameters
    ----------
    path : str or Path
        Text file: an optional ``# timecode format v2`` header, then one presentation time in
        milliseconds per frame, in frame order; blank lines and ``#`` comments are skipped.

    Returns
    -------
    t_s : ndarray, shape (N,)
        Times in s, from the file as written (not shifted to start at 0).

    Raises
    ------
    InputError
        A missing file, a line that is not a number (named with its line number), fewer than
        two times, or times that do not increase.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: timestamps file not found")
    t_ms = []
    for line_no, line in enumerate(path.read_text().splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        try:
            t_ms.append(float(text))
        except ValueError:
            raise InputError(f"{path}, line {line_no}: {text!r} is not a time in ms "
                             "(expected timecode format v2: one number per frame)") from None
    t_s = np.asarray(t_ms, float) / 1000.0
    if len(t_s) < 2:
        raise InputError(f"{path}: {len(t_s)} frame times (expected one per frame, at least 2)")
    if not np.all(np.isfinite(t_s)):
        raise InputError(f"{path}: a time that is not finite")
    steps = np.diff(t_s)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise InputError(f"{path}: frame {k + 1} at {1000 * t_s[k + 1]:g} ms does not follow "
                         f"frame {k} at {1000 * t_s[k]:g} ms (times must increase)")
    return t_s


def _scan_packets(path) -> tuple[int, bool, bool]:
    """Packets with data in a stream, whether any carries a timestamp, and whether its
    decoder reorders frames (B-frames)."""
    import av

    from cvsflow.io.media import _open_av

    container = _open_av(path)
    try:
        stream = container.streams.video[0]
        n = 0
        timed = reorders = False
        for packet in container.demux(stream):
            if not packet.size:
                continue
            n += 1
            timed |= packet.pts is not None
            if n <= 32 and not reorders:  # the reorder delay shows within the first GOP's frames
                with contextlib.suppress(av.error.FFmpegError):  # a damaged packet: the next
                    packet.decode()
                reorders = bool(stream.codec_context.has_b_frames)
    finally:
        container.close()
    return n, timed, reorders


def remux_with_times(src, dst, fps=None, timestamps_s=None) -> dict:
    """Copy a raw stream's packets into an MP4 whose frames carry the given times.

    Parameters
    ----------
    src : str or Path
        The raw stream (``.h264``, ``.264``, ``.hevc``, ``.h265``) or any video whose packets
        carry no timestamps.
    dst : str or Path
        MP4 to write; must not exist (nothing is overwritten) and must not be ``src``.
    fps : float, optional
        Nominal frame rate: frame k at k / fps. Frame drops and a variable rate are then
        invisible: prefer ``timestamps_s``.
    timestamps_s : array_like, shape (N,), optional
        Each frame's time, s (:func:`read_timecodes_v2`), one per packet; shifted to start
        at 0.

    Returns
    -------
    summary : dict
        ``n_frames``, ``duration_s`` (last frame's time), ``period_s`` (median step),
        ``source`` ("timestamps" or "fps").

    Raises
    ------
    InputError
        Neither or both of ``fps`` and ``timestamps_s``; ``dst`` existing or equal to
        ``src``; ``src`` not a video, with timestamps of its own, with B-frames (decode order
        is not presentation order, so packet k is not frame k), or with another count of
        frames than of times. No file is left behind on an error.
    """
    import av

    src, dst = Path(src), Path(dst)
    if (fps is None) == (timestamps_s is None):
        raise InputError(f"{src}: give the frame times either as a frame rate or as a "
                         "timestamps file (one of them)")
    if dst.exists():
        raise InputError(f"{dst}: exists; the remuxed video is written to a new file only")
    if dst.resolve() == src.resolve():
        raise InputError(f"{dst}: is the input; write the remuxed video beside it")
    if dst.suffix.lower() not in (".mp4", ".mov"):
        raise InputError(f"{dst}: expected an .mp4 or .mov output")
    n_packets, timed, reorders = _scan_packets(src)
    if timed:
        raise InputError(f"{src}: its packets carry timestamps already; it is read as it is")
    if reorders:
        raise InputError(
            f"{src}: the stream has B-frames (frames decode out of display order), so times "
            "cannot be given packet by packet; remux it with FFmpeg, which orders them: "
            f"ffmpeg -fflags +genpts -r <fps> -i {src.name} -c copy {dst.name}")
    if fps is not None:
        fps = float(fps)
        if not (np.isfinite(fps) and fps > 0):
            raise InputError(f"{src}: frame rate {fps} (expected > 0 frames/s)")
        t_s = np.arange(n_packets) / fps
        source = "fps"
    else:
        t_s = np.asarray(timestamps_s, float)
        if len(t_s) != n_packets:
            raise InputError(f"{src}: {n_packets} frames, but {len(t_s)} timestamps (expected "
                             "one per frame: the timestamps file of this recording?)")
        t_s = t_s - t_s[0]
        source = "timestamps"
    ticks = np.rint(t_s / float(MP4_TIME_BASE)).astype(np.int64)
    if np.any(np.diff(ticks) <= 0):
        raise InputError(f"{src}: two frame times closer than {float(MP4_TIME_BASE):.2g} s")
    inp = av.open(str(src))
    try:
        out = av.open(str(dst), "w")
        try:
            in_stream = inp.streams.video[0]
            out_stream = out.add_stream_from_template(in_stream)
            out_stream.time_base = MP4_TIME_BASE
            k = 0
            for packet in inp.demux(in_stream):
                if not packet.size:
                    continue
                packet.stream = out_stream
                packet.time_base = MP4_TIME_BASE
                packet.pts = packet.dts = int(ticks[k])
                out.mux(packet)
                k += 1
        finally:
            out.close()
    except (av.error.FFmpegError, OSError, ValueError) as exc:
        dst.unlink(missing_ok=True)
        raise InputError(f"{src}: could not be written as {dst} ({exc})") from exc
    finally:
        inp.close()
    period = sample_period(t_s)
    log.info("%s: %d frames over %.3f s (median period %.6f s, from %s) written to %s", src,
             n_packets, t_s[-1], period, source, dst)
    return {"n_frames": int(n_packets), "duration_s": float(t_s[-1]), "period_s": period,
            "source": source}
