"""Chessboard corners in every video frame: the ``corners.parquet`` table, in chunks on several cores.

``extract_corners`` gives the corners table of docs/contracts.md. It follows the board from
frame to frame (:mod:`cvsflow.corners.track`) and runs the full detector
(:mod:`cvsflow.corners.detect`) only when it must; bench/bench_corners.py measures it per
resolution against the renderer's truth. ``summarise_corners`` gives corners_summary.yaml.

``extract_corners`` starts afresh (no tracking state, full detection) at every frame whose
index is a multiple of ``restart_every``. A chunk of frames that starts at such a frame
therefore gives exactly the rows a single pass gives for those frames, and the chunks, joined
in order (``merge_corner_chunks``), give exactly the single-pass table.
``extract_corners_parallel`` runs the chunks in worker processes, one per core.

A frame source is a callable ``source(start, stop)`` that yields ``(frame, t_s, gray)`` for
the frames ``[start, stop)`` (``stop`` None: to the end), e.g.
``functools.partial(cvsflow.io.media.iter_video_gray, path)``; workers call it to read
their own chunk, so it must be picklable (a module-level function or a ``partial`` of one).
"""

from __future__ import annotations

import gc
import itertools
import logging
import multiprocessing
import time
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor, wait
from functools import partial

import cv2
import numpy as np
import pandas as pd

from cvsflow.board import (
    CORNER_COLUMNS,
    CornerRows,
    board_name,
    board_pattern,
    board_type,
    extract_aprilgrid_corners,
    extract_charuco_corners,
    is_charuco,
)
from cvsflow.corners.grid import MAX_GRID_DEVIATION_FRAC
from cvsflow.corners.track import _CornerFollower
from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)

# extract_corners starts afresh (full detection, no state) at frame indices that are multiples
# of this: 10 s at 30 fps. Lets a video be cut into chunks (one per core) whose tables join
# into exactly the single-pass table. Each restart costs a new search for the board, which with
# a hand over it lasts until the board is next seen whole (the frames between are tracked back
# from there): every 150 frames that cost 0.18 ms of each 640x480 frame's 0.93 ms and 0.14 of
# each 1280x720 frame's 1.86 ms on the 12 s realistic renders. 300 still cuts a 90 s take into
# 9 chunks.
RESTART_EVERY_FRAMES = 300


def extract_corners(
    frames: Iterable[tuple[int, float, np.ndarray]],
    board: dict,
    subpix_window_px: int = 5,
    n_frames: int | None = None,
    log_every: int = 300,
    flags: int | None = None,
    max_continuity_gap: int = 3,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    track: bool = True,
    restart_every: int | None = RESTART_EVERY_FRAMES,
    keep_partial: bool = True,
) -> pd.DataFrame:
    """Chessboard corners of every video frame, the same physical corner under the same index.

    Parameters
    ----------
    frames : iterable of (int, float, ndarray)
        ``(frame, t_s, gray)``: frame index, video time (s) and 8-bit grayscale image (H, W),
        e.g. ``cvsflow.io.media.iter_video_gray``.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m`` (m); with ``type: charuco`` (and
        ``marker_m``, ``dictionary``) ``cvsflow.board.extract_charuco_corners`` makes the table
        instead, with ``type: aprilgrid`` ``cvsflow.board.extract_aprilgrid_corners`` (the
        tracking arguments do not apply: the markers or tags name every corner).
    subpix_window_px : int
        Largest cornerSubPix half window, pixels (shrunk for far boards, see ``_subpix_window``).
    n_frames : int, optional
        Number of frames expected, for progress messages only.
    log_every : int
        Log progress every this many frames.
    flags : int, optional
        ``findChessboardCorners`` flags for every frame. By default adaptive threshold and
        normalisation, plus FAST_CHECK when no board was found in the last
        ``max_continuity_gap`` frames.
    max_continuity_gap : int
        For boards whose ends look alike: the previous found frame is used for temporal
        continuity only if at most this many frames back.
    max_grid_deviation : float
        A frame with a corner farther than this share of its local grid spacing from where
        its grid neighbours put it, even after a second refinement, counts as not found (see
        ``detect_corners``).
    track : bool
        Follow the board from the last frame where it was seen (``track_corners``) and run the
        full detector only where that fails; False runs ``detect_corners`` on every frame.
    restart_every : int or None
        Frames whose index is a multiple of this start afresh: no tracking state, no
        continuity, full detection. A frame's result then depends only on the frames since the
        last such index, so a video cut into chunks at multiples of it
        (``extract_corners_parallel``) gives exactly the table of one pass. None: never.
    keep_partial : bool
        Frames where the tracked board is partly hidden (a hand over it: ``partial``; the
        image border: ``out_of_view``) keep the corners that pass their local checks, with
        their indices, as do frames where the detector finds the grid but some corners fail
        the neighbour check (``partial``: a hand over the board with no full view before);
        False counts them as not found (the former table).

    Returns
    -------
    corners : DataFrame
        ``frame`` (int64), ``t_s`` (float64, s), ``found`` (bool), ``corner`` (int64),
        ``u_px``, ``v_px`` (float64, distorted pixels). A found frame has one row per inner
        corner it keeps (all of them, or with ``keep_partial`` those of a partly hidden board),
        corner k at board point (k % nx, k // nx) * square_m; a frame without a board
        has one row with ``corner = -1`` and NaN pixels. ``attrs`` holds counts:
        ``n_frames``, ``n_found``, ``order_methods`` (dict method -> frames: ``tracked``,
        ``out_of_view`` (followed partly out of the image), ``partial`` (a hand over it),
        ``quick`` (the quick search), ``*_back`` (tracked backwards from a later frame),
        ``detect_corners``' methods for frames where the full detector ran; without a board:
        ``not_found`` (a detector looked), ``not_searched`` (the search's back-off skipped
        the frame and no board could be tracked into it), ``inconsistent``, ``cv_error``,
        ``undecodable`` (a frame given as None: the decoder refused it)), ``n_predicted`` (the
        frames among them that ``cvsflow.corners.predict.predict_corners`` followed).

    Raises
    ------
    InputError
        A frame that is not a 2-D uint8 image.
    """
    if is_charuco(board):  # the markers name each corner: every frame detected on its own
        return extract_charuco_corners(frames, board, subpix_window_px, n_frames, log_every,
                                       keep_partial)
    if board_type(board) == "aprilgrid":  # so do the tags
        return extract_aprilgrid_corners(frames, board, n_frames, log_every)
    rows = CornerRows(int(np.prod(board_pattern(board))))
    methods: dict[str, int] = {}
    follower = _CornerFollower(board, subpix_window_px, max_grid_deviation,
                               max_continuity_gap, flags, track, restart_every, keep_partial)
    t_start = time.perf_counter()
    n_done = n_found = 0

    def record(results):
        nonlocal n_found
        for frame, t_s, corners_px, method in results:
            methods[method] = methods.get(method, 0) + 1
            n_found += corners_px is not None
            rows.add(frame, t_s, corners_px)

    for frame, t_s, gray in _read_ahead(frames):
        if gray is None:  # the decoder refused it (iter_video_gray's ``undecodable``)
            record(follower.push_undecodable(int(frame), float(t_s)))
            n_done += 1
            continue
        gray = np.asarray(gray)
        if gray.ndim != 2 or gray.dtype != np.uint8:
            raise InputError(
                f"video frame {frame}: expected an 8-bit grayscale image, got dtype "
                f"{gray.dtype}, shape {gray.shape}"
            )
        record(follower.push(int(frame), float(t_s), gray))
        n_done += 1
        if log_every and n_done % log_every == 0:
            rate = n_done / max(time.perf_counter() - t_start, 1e-9)
            of_total = f" of {n_frames}" if n_frames else ""
            log.info(
                "corners: %d%s frames done, board found in %d (%.1f frames/s)",
                n_done,
                of_total,
                n_found,
                rate,
            )
    record(follower.finish())
    elapsed = time.perf_counter() - t_start
    if n_done == 0:
        raise InputError("video: no frames to extract corners from (expected at least one)")
    corners = rows.table()
    corners.attrs = {"n_frames": n_done, "n_found": n_found, "order_methods": methods,
                     "n_cv_errors": follower.cv_errors, "n_predicted": follower.n_predicted}
    if follower.cv_errors:
        log.warning("corners: %d OpenCV calls failed (frames went on without them)",
                    follower.cv_errors)
    log.info(
        "corners: board found in %d of %d frames (%.1f %%), %.1f frames/s; order decided by %s",
        n_found,
        n_done,
        100.0 * n_found / n_done,
        n_done / max(elapsed, 1e-9),
        methods,
    )
    if n_done - n_found:
        log.warning("corners: %d frames without a board kept as found=False", n_done - n_found)
    if methods.get("undecodable"):
        log.warning("corners: %d frames could not be decoded (a damaged recording); kept as "
                    "found=False, and the board is searched for afresh after each",
                    methods["undecodable"])
    if methods.get("inconsistent"):
        log.warning(
            "corners: %d frames had a corner off its grid neighbours by more than %.2f of "
            "its local square size after refinement; counted as not found",
            methods["inconsistent"],
            max_grid_deviation,
        )
    if methods.get("unresolved"):
        log.warning(
            "corners: %d frames had an undecidable 180-degree corner order (board ends alike, "
            "no recent previous frame); OpenCV's order kept",
            methods["unresolved"],
        )
    return corners


# Frames are taken from the source in runs of up to this many (and this many bytes): decoding
# a run back to back keeps the decoder's working set in the cache, which tracking each frame
# in between evicts. On the 12 s realistic 640x480 clip the stage took 1.00-1.05 ms a frame
# against 1.11-1.13 ms frame by frame (runs of 16; runs of 4-8 gained little), at 1080p
# 5.2 against 5.5 ms.
READ_AHEAD_FRAMES = 16
READ_AHEAD_BYTES = 32 * 2**20


def _read_ahead(frames: Iterable[tuple[int, float, np.ndarray | None]]) -> Iterator:
    """``frames`` in order, pulled from the source a run at a time (``READ_AHEAD_FRAMES``,
    ``READ_AHEAD_BYTES``)."""
    it = iter(frames)
    while True:
        run, size = [], 0
        for item in it:
            run.append(item)
            gray = item[2]
            size += getattr(gray, "nbytes", 0)
            if len(run) >= READ_AHEAD_FRAMES or size >= READ_AHEAD_BYTES:
                break
        if not run:
            return
        yield from run


def summarise_corners(corners: pd.DataFrame, timing: dict | None = None) -> dict:
    """The corners stage's summary (corners_summary.yaml): counts, no wall times.

    Parameters
    ----------
    corners : DataFrame
        corners.parquet table with ``extract_corners``' ``attrs``.
    timing : dict, optional
        ``cvsflow.io.media.video_timing`` of the video.

    Returns
    -------
    summary : dict
        ``n_frames_decoded``, ``n_undecodable`` (frames whose packets the decoder refused:
        rows with found=False), ``n_found``, ``found_share`` (over all frames),
        ``frames_by_method`` (method -> frames: how each frame was decided; ``not_found``,
        ``not_searched``, ``inconsistent``, ``cv_error``, ``undecodable`` are the reasons a
        frame has no board),
        ``n_cv_errors``, ``n_predicted`` (frames followed by prediction rather than optical
        flow), ``corners_per_found_frame``
        (min, median, max); ``detector`` (an AprilGrid's tag detector); with ``timing``:
        ``n_frames_header``, ``n_frames_demuxed``,
        ``n_dropped``, ``dropped_gaps`` (``[after_frame, missing]``), ``period_s`` (median),
        ``period_min_s``, ``period_max_s``, ``codec``, ``key_frame_share`` (key frames over
        demuxed frames) and ``inter_coded`` (some frame coded from another: a still board
        then errs by a pose-like motion its corners' residual does not show, which model (T)
        adds, :data:`cvsflow.uncertainty.features.STILL_SPEED_PX`).
    """
    per_frame = corners.groupby("frame")["found"].first()
    n_per = corners[corners["found"]].groupby("frame").size()
    attrs = corners.attrs
    n_undecodable = int(attrs.get("order_methods", {}).get("undecodable", 0))
    out = {
        "n_frames_decoded": int(len(per_frame)) - n_undecodable,
        "n_undecodable": n_undecodable,
        "n_found": int(per_frame.sum()),
        "found_share": float(per_frame.mean()) if len(per_frame) else 0.0,
        "frames_by_method": {str(k): int(v) for k, v in
                             sorted(attrs.get("order_methods", {}).items())},
        "n_cv_errors": int(attrs.get("n_cv_errors", 0)),
        "n_predicted": int(attrs.get("n_predicted", 0)),
        "corners_per_found_frame": [int(n_per.min()), float(n_per.median()), int(n_per.max())]
        if len(n_per) else [0, 0.0, 0],
    }
    if "detector" in attrs:  # an AprilGrid's tag detector (pupil-apriltags may be missing)
        out["detector"] = str(attrs["detector"])
    if timing is not None:
        dt = np.diff(np.asarray(timing["t_s"], dtype=np.float64))
        out.update({
            "n_frames_header": int(timing["n_frames_header"]),
            "n_frames_demuxed": int(timing["n_frames"]),
            "n_dropped": int(timing["n_dropped"]),
            "dropped_gaps": [[int(a), int(b)] for a, b in timing["gaps"]],
            "period_s": float(timing["period_s"]),
            "period_min_s": float(dt.min()) if len(dt) else 0.0,
            "period_max_s": float(dt.max()) if len(dt) else 0.0,
        })
        if "n_key_frames" in timing:
            out.update({"codec": str(timing["codec"]),
                        "key_frame_share": timing["n_key_frames"] / max(int(timing["n_frames"]), 1),
                        "inter_coded": bool(timing["inter_coded"])})
    return out


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
        Passed to ``extract_corners``.

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
        "n_predicted": sum(int(c.attrs.get("n_predicted", 0)) for c in ordered),
    }
    detectors = {c.attrs["detector"] for c in ordered if "detector" in c.attrs}
    if detectors:
        merged.attrs["detector"] = " | ".join(sorted(detectors))
    return merged


def _board_seen(corners: pd.DataFrame, board: dict) -> pd.DataFrame:
    """``corners``, or an InputError when an AprilGrid was found in none of its frames (a
    chessboard's video keeps its not-found frames, as it always has)."""
    if board_type(board) == "aprilgrid" and not corners.attrs.get("n_found", 0):
        raise InputError(
            f"video: the {board_name(board)} was found in none of its {corners.attrs.get('n_frames', 0)} "
            f"frames ({corners.attrs.get('detector', '')}); expected it in at least one: check the "
            f"board block or target file against the print ({board!r}: tag counts, tag36h11, a 2-bit border)"
        )
    return corners


class _CountedSource:
    """A frame source that reports each frame it has given: ``report(n)``, n frames so far."""

    def __init__(self, source, report):
        self.source, self.report = source, report

    def __call__(self, start, stop):
        for n, item in enumerate(self.source(start, stop), start=1):
            yield item
            self.report(n)


#: A worker's counter of frames read, shared with the parent (set by ``_init_worker``).
_FRAMES_READ = None


def _init_worker(counter) -> None:
    global _FRAMES_READ
    _FRAMES_READ = counter


def _count_one(counter, _n) -> None:
    with counter.get_lock():
        counter.value += 1


def _run_chunk(args) -> pd.DataFrame:
    """Worker: one chunk, on one OpenCV thread, its frames counted for the parent's progress."""
    source, start, stop, board, kwargs = args
    cv2.setNumThreads(1)
    if _FRAMES_READ is not None:
        source = _CountedSource(source, partial(_count_one, _FRAMES_READ))
    return extract_corners_range(source, start, stop, board, **kwargs)


def extract_corners_parallel(
    source: FrameSource,
    n_frames: int,
    board: dict,
    n_workers: int = 2,
    progress: Callable[[int], None] | None = None,
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
    progress : callable, optional
        ``progress(n)``: n frames read so far over all workers (about every 0.5 s from several
        workers; after every frame from one), e.g. a :class:`cvsflow.io.progress.Progress`.
    **kwargs
        Passed to ``extract_corners`` (``restart_every`` sets the cut points).

    Returns
    -------
    corners : DataFrame
        As ``extract_corners`` on the whole video.

    Raises
    ------
    InputError
        An AprilGrid found in no frame (its board block or target file does not describe the
        grid filmed: a tag count, family or border that is not the print's).

    Notes
    -----
    One contiguous chunk per worker, so each worker seeks once. Workers are forked where the
    platform allows (no re-import of the package); each uses one OpenCV thread.
    """
    restart_every = kwargs.get("restart_every", RESTART_EVERY_FRAMES)
    ranges = chunk_ranges(n_frames, n_workers, restart_every) if n_workers > 1 and restart_every else []
    if len(ranges) <= 1:
        counted = _CountedSource(source, progress) if progress else source
        return _board_seen(extract_corners_range(counted, 0, None, board, **kwargs), board)
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else None)
    jobs = [(source, a, b, board, kwargs) for a, b in ranges]
    log.info("corners: %d chunks %s on %d processes", len(ranges), ranges, n_workers)
    # A child forked while OpenCV's thread pool runs in this process hangs when it touches
    # the pool: shrink the pool to this thread before forking, restore it afterwards.
    n_threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    # A child also inherits this process's unreachable PyAV containers (reference cycles the
    # collector has not freed yet, e.g. of video_timing's read) with their decoders' slice
    # threads, which do not exist in the child: collecting one there waits forever for those
    # threads to join. Free them here, where the threads are, and freeze what is left so that
    # no child's collector frees an object it inherited.
    gc.collect()
    gc.freeze()
    try:
        counter = context.Value("q", 0) if progress else None
        with ProcessPoolExecutor(max_workers=min(n_workers, len(ranges)), mp_context=context,
                                 initializer=_init_worker, initargs=(counter,)) as ex:
            futures = [ex.submit(_run_chunk, job) for job in jobs]
            while progress and wait(futures, timeout=0.5).not_done:
                progress(counter.value)
            chunks = [f.result() for f in futures]
        if progress:
            progress(counter.value)
    finally:
        gc.unfreeze()
        cv2.setNumThreads(n_threads)
    corners = _board_seen(merge_corner_chunks(chunks), board)
    a = corners.attrs
    log.info(
        "corners: board found in %d of %d frames (all chunks); frames by method %s",
        a["n_found"],
        a["n_frames"],
        a["order_methods"],
    )
    return corners
