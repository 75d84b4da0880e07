"""Corners of a video in chunks, on several cores, with the table of a single pass.

``cvsflow.pose.extract_corners`` starts afresh (no tracking state, full detection) at every
frame whose index is a multiple of ``restart_every``. A chunk of frames that starts at such a
frame therefore gives exactly the rows a single pass gives for those frames, and the chunks,
joined in order (``merge_corner_chunks``), give exactly the single-pass table.
``extract_corners_parallel`` runs the chunks in worker processes, one per core.

A frame source is a callable ``source(start, stop)`` that yields ``(frame, t_s, gray)`` for
the frames ``[start, stop)`` (``stop`` None: to the end), e.g.
``functools.partial(cvsflow.io.media.iter_video_gray, path)``; workers call it to read
their own chunk, so it must be picklable (a module-level function or a ``partial`` of one).
"""

from __future__ import annotations

import itertools
import logging
import multiprocessing
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor

import cv2
import numpy as np
import pandas as pd

from cvsflow.errors import InputError
from cvsflow.pose import CORNER_COLUMNS, RESTART_EVERY_FRAMES, extract_corners

log = logging.getLogger(__name__)

_DTYPES = {
    "frame": "int64",
    "t_s": "float64",
    "found": "bool",
    "corner": "int64",
    "u_px": "float64",
    "v_px": "float64",
}
FrameSource = Callable[[int, int | None], Iterable[tuple[int, float, np.ndarray]]]


def chunk_ranges(
    n_frames: int, n_chunks: int, restart_every: int = RESTART_EVERY_FRAMES
) -> list[tuple[int, int | None]]:
    """Frame ranges ``[start, stop)`` of about equal length, cut at multiples of restart_every.

    Parameters
    ----------
    n_frames : int
        Frames in the video (as its container states; the last range is open, so a count
        that is off by a few frames does no harm).
    n_chunks : int
        Ranges wanted; fewer are returned when the video has fewer restart blocks.
    restart_every : int
        ``extract_corners``' restart period, frames.

    Returns
    -------
    ranges : list of (int, int or None)
        Consecutive ranges covering frame 0 onwards; the last one's stop is None.
    """
    if n_chunks < 1 or restart_every < 1:
        raise ValueError(f"n_chunks={n_chunks}, restart_every={restart_every}: expected >= 1")
    n_blocks = max(1, -(-max(int(n_frames), 0) // restart_every))
    n_chunks = min(n_chunks, n_blocks)
    cuts = [round(i * n_blocks / n_chunks) * restart_every for i in range(n_chunks)]
    return [(a, b) for a, b in zip(cuts, cuts[1:], strict=False)] + [(cuts[-1], None)]


def _frames_in_range(
    source: FrameSource, start: int, stop: int | None
) -> Iterator[tuple[int, float, np.ndarray]]:
    """The source's frames [start, stop), checked to come in that order without gaps."""
    expected = start
    for frame, t_s, gray in source(start, stop):
        if frame != expected:
            raise InputError(
                f"video chunk [{start}, {stop}): got frame {frame}, expected {expected} "
                "(the frame source must yield consecutive frames from the chunk's start)"
            )
        yield frame, t_s, gray
        expected += 1


def extract_corners_range(
    source: FrameSource, start: int, stop: int | None, board: dict, **kwargs
) -> pd.DataFrame:
    """``extract_corners`` on the frames ``[start, stop)`` of a frame source.

    Parameters
    ----------
    source : callable
        ``source(start, stop)`` yielding ``(frame, t_s, gray)`` (see the module notes).
    start, stop : int, int or None
        Frame range; ``start`` a multiple of ``restart_every`` for the rows to equal those
        of a single pass.
    board : dict
    **kwargs
        Passed to ``cvsflow.pose.extract_corners``.

    Returns
    -------
    corners : DataFrame
        corners.parquet rows of those frames (``attrs`` counts of this chunk).

    Raises
    ------
    InputError
        A chunk without frames, or a source yielding other frames than asked for.
    """
    restart_every = kwargs.get("restart_every", RESTART_EVERY_FRAMES)
    if restart_every and start % restart_every:
        raise ValueError(
            f"chunk start {start} is not a multiple of restart_every={restart_every}; its rows "
            "would differ from a single pass"
        )
    frames = _frames_in_range(source, start, stop)
    if start > 0:
        first = next(frames, None)
        if first is None:  # past the end: the container's frame count was too high
            empty = pd.DataFrame({c: pd.Series(dtype=t) for c, t in _DTYPES.items()})
            empty.attrs = {"n_frames": 0, "n_found": 0, "order_methods": {}, "n_cv_errors": 0}
            return empty
        frames = itertools.chain([first], frames)
    return extract_corners(frames, board, **kwargs)


def merge_corner_chunks(chunks: list[pd.DataFrame]) -> pd.DataFrame:
    """Join the tables of consecutive chunks into one corners table.

    Parameters
    ----------
    chunks : list of DataFrame
        corners.parquet tables of consecutive frame ranges, in any order.

    Returns
    -------
    corners : DataFrame
        Rows in frame order, index 0..n-1; ``attrs`` summed over the chunks
        (``n_frames``, ``n_found``, ``order_methods``).

    Raises
    ------
    InputError
        No chunks, missing columns, or chunks that overlap or leave frames out.
    """
    if not chunks:
        raise InputError("corner chunks: none given (expected at least one table)")
    for i, c in enumerate(chunks):
        missing = [col for col in CORNER_COLUMNS if col not in c.columns]
        if missing:
            raise InputError(f"corner chunk {i}: missing columns {missing}")
    ordered = sorted((c for c in chunks if len(c)), key=lambda c: int(c["frame"].iloc[0]))
    if not ordered:
        raise InputError("corner chunks: all empty (expected at least one frame)")
    for a, b in zip(ordered, ordered[1:], strict=False):
        last, first = int(a["frame"].iloc[-1]), int(b["frame"].iloc[0])
        if first != last + 1:
            raise InputError(
                f"corner chunks: a chunk ending at frame {last} is followed by one starting "
                f"at frame {first} (expected {last + 1}: chunks must be consecutive)"
            )
    merged = pd.concat(ordered, ignore_index=True)[CORNER_COLUMNS]
    methods: dict[str, int] = {}
    for c in ordered:
        for k, v in c.attrs.get("order_methods", {}).items():
            methods[k] = methods.get(k, 0) + v
    merged.attrs = {
        "n_frames": sum(int(c.attrs.get("n_frames", c["frame"].nunique())) for c in ordered),
        "n_found": sum(int(c.attrs.get("n_found", 0)) for c in ordered),
        "order_methods": methods,
        "n_cv_errors": sum(int(c.attrs.get("n_cv_errors", 0)) for c in ordered),
    }
    return merged


def _run_chunk(args) -> pd.DataFrame:
    """Worker: one chunk, on one OpenCV thread."""
    source, start, stop, board, kwargs = args
    cv2.setNumThreads(1)
    return extract_corners_range(source, start, stop, board, **kwargs)


def extract_corners_parallel(
    source: FrameSource,
    n_frames: int,
    board: dict,
    n_workers: int = 2,
    **kwargs,
) -> pd.DataFrame:
    """Corners of a whole video, its chunks on ``n_workers`` processes; same table as one pass.

    Parameters
    ----------
    source : callable
        ``source(start, stop)`` yielding ``(frame, t_s, gray)``; picklable.
    n_frames : int
        Frames in the video (container count), to cut the chunks.
    board : dict
    n_workers : int
        Processes (cores). 1 runs a single pass in this process.
    **kwargs
        Passed to ``cvsflow.pose.extract_corners`` (``restart_every`` sets the cut points).

    Returns
    -------
    corners : DataFrame
        As ``extract_corners`` on the whole video.

    Notes
    -----
    One contiguous chunk per worker, so each worker seeks once. Workers are forked where the
    platform allows (no re-import of the package); each uses one OpenCV thread.
    """
    restart_every = kwargs.get("restart_every", RESTART_EVERY_FRAMES)
    if n_workers <= 1 or not restart_every:
        return extract_corners_range(source, 0, None, board, **kwargs)
    ranges = chunk_ranges(n_frames, n_workers, restart_every)
    if len(ranges) == 1:
        return extract_corners_range(source, 0, None, board, **kwargs)
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else None)
    jobs = [(source, a, b, board, kwargs) for a, b in ranges]
    log.info("corners: %d chunks %s on %d processes", len(ranges), ranges, n_workers)
    # A child forked while OpenCV's thread pool runs in this process hangs when it touches
    # the pool: shrink the pool to this thread before forking, restore it afterwards.
    n_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        with ProcessPoolExecutor(max_workers=min(n_workers, len(ranges)), mp_context=context) as ex:
            chunks = list(ex.map(_run_chunk, jobs))
    finally:
        cv2.setNumThreads(n_threads)
    corners = merge_corner_chunks(chunks)
    a = corners.attrs
    log.info(
        "corners: board found in %d of %d frames (all chunks); frames by method %s",
        a["n_found"],
        a["n_frames"],
        a["order_methods"],
    )
    return corners
