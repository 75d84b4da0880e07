"""Following the chessboard from frame to frame: ``track_corners`` and the per-frame decisions.

``track_corners`` moves the previous frame's corners by optical flow on a shrunk image, then
refines them at full size and applies the grid, saddle and square-colour checks. Where the
board was followed in the two frames before, the ``_CornerFollower`` first tries the cheaper
:func:`cvsflow.corners.predict.predict_corners` (constant velocity, no flow), which hands any
frame where something changed to ``track_corners``. The
``_CornerFollower`` behind :func:`cvsflow.corners.extract.extract_corners` keeps following a board while
it is partly out of view or under a hand, looks for a lost board with the quick detector,
backing off while it stays lost (the frames in between wait, within a memory bound, and are
tracked backwards from where it is found), and runs the full detector (on the shrunk image)
only right after the tracker loses the board and every ``DEEP_SEARCH_EVERY`` frames while lost.
"""

from __future__ import annotations

import collections
import logging

import cv2
import numpy as np

from cvsflow.corners.detect import (
    QUICK_MIN_SQUARE_PX,
    VIDEO_FIND_FLAGS,
    VIDEO_SEARCH_FLAGS,
    detect_corners,
    quick_detect_corners,
)
from cvsflow.corners.grid import (
    LK_CRITERIA,
    MAX_GRID_DEVIATION_FRAC,
    MIN_TRACKED_CORNERS,
    _grid_points,
    _inside,
    _median_spacing,
    _track_scales,
)
from cvsflow.corners.predict import predict_corners
from cvsflow.corners.refine import (
    MIN_PATTERN_CONTRAST,
    _follow_partial,
    _partial_without,
    _refine_corners,
    _saddle_ok,
    board_squares_pattern_ok,
)

log = logging.getLogger(__name__)

def track_corners(
    prev_gray: np.ndarray,
    gray: np.ndarray,
    prev_px: np.ndarray,
    board: dict,
    subpix_window_px: int = 5,
    max_grid_deviation: float = MAX_GRID_DEVIATION_FRAC,
    hidden: np.ndarray | None = None,
) -> tuple[np.ndarray | None, str]:
    """Board corners of a frame from those of an earlier frame (optical flow, then checks).

    Parameters
    ----------
    prev_gray : ndarray, shape (H, W), uint8
        The earlier frame.
    gray : ndarray, shape (H, W), uint8
        This frame.
    prev_px : ndarray, shape (nx * ny, 2)
        Corners of the earlier frame in board order, pixels; corners outside the image (a
        board partly out of view) are predictions.
    board : dict
    subpix_window_px : int
        Largest cornerSubPix half window, pixels.
    max_grid_deviation : float
        As in ``detect_corners``.
    hidden : ndarray of bool, shape (nx * ny,), optional
        Corners a hand hid in the earlier frame. Where one of them is still off its grid
        neighbours after the first cornerSubPix, the hand is taken to be there still: the
        frame goes straight to the partial check, without the second cornerSubPix that
        rescues a corner the flow put a little off (it cannot rescue one under a hand).

    Returns
    -------
    corners_px : ndarray, shape (nx * ny, 2), float64, or None
        With ``"tracked"``: the refined corners in board order. With ``"out_of_view"``: where
        the corners are (refined where inside the image, predicted elsewhere), to track from.
        None with ``"lost"``.
    method : str
        ``"tracked"``: every corner inside the image, refined, consistent with its grid
        neighbours, showing the chessboard's saddle (``_saddle_ok``), in the order the colours
        of the squares confirm (``order_corners``), and every square of the board of the right
        colour (``board_squares_pattern_ok``). ``"partial"``: some corners under a hand
        dropped (NaN), the others passing the checks of a partly hidden board.
        ``"out_of_view"``: the board is followed but a corner is within the border margin
        (``TRACK_BORDER_PX`` or ``TRACK_BORDER_FRAC`` of the square size) of the border or
        outside (the frame has no whole board). ``"lost"``: any check failed; the caller
        falls back to ``detect_corners``.

    Notes
    -----
    ``cv2.calcOpticalFlowPyrLK`` (pyramidal Lucas-Kanade) on the corners inside the earlier
    image, a RANSAC homography (``cv2.findHomography``) from grid to image through them to
    place the others and to reject corners the flow lost, then ``refine_corners``. A one-square
    slip of the whole grid keeps its geometry; the colour checks catch it.
    """
    h, w = gray.shape
    grid = _grid_points(board)
    prev = np.asarray(prev_px, dtype=np.float32).reshape(-1, 2)
    seen = np.isfinite(prev).all(axis=1) & (
        (prev[:, 0] >= 0) & (prev[:, 0] <= w - 1) & (prev[:, 1] >= 0) & (prev[:, 1] <= h - 1)
    )
    if seen.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    sc = _track_scales(prev, board, gray.shape)
    f = 2 ** sc["lk_shrink"]
    start = prev[seen].reshape(-1, 1, 2)
    if f > 1:
        # Area-averaged pixel i of the shrunk image covers full pixels [f i, f (i + 1)).
        small_prev, small = _shrunk(prev_gray, f), _shrunk(gray, f)
        start = ((start + 0.5) / f - 0.5).astype(np.float32)
    else:
        small_prev, small = prev_gray, gray
    moved, status, _ = cv2.calcOpticalFlowPyrLK(
        small_prev, small, start, None,
        winSize=(sc["lk_window"], sc["lk_window"]), maxLevel=sc["lk_levels"],
        criteria=LK_CRITERIA,
    )
    if f > 1:
        moved = (moved + 0.5) * f - 0.5
    ok = status.ravel() == 1
    if ok.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    H, inliers = cv2.findHomography(
        grid[seen][ok], moved.reshape(-1, 2)[ok], cv2.RANSAC, sc["homography_rms"]
    )
    if H is None or inliers.sum() < MIN_TRACKED_CORNERS:
        return None, "lost"
    p = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    inlier = inliers.ravel() == 1
    p[np.flatnonzero(seen)[ok][inlier]] = moved.reshape(-1, 2)[ok][inlier]
    if not _inside(p, w, h, 0.0).all():
        return _follow_partial(gray, p, _inside(p, w, h, sc["border"]), grid, board,
                               subpix_window_px, sc, max_grid_deviation)
    corners, first = _refine_corners(gray, p, board, subpix_window_px, max_grid_deviation,
                                     hidden)
    if corners is None:  # a corner off its neighbours: hidden (a hand) or misplaced
        return _follow_partial(gray, p, np.ones(len(p), bool), grid, board, subpix_window_px,
                               sc, max_grid_deviation, "partial", first)
    inner = _inside(corners, w, h, sc["border"])
    if not inner.all():
        return _follow_partial(gray, corners, inner, grid, board, subpix_window_px, sc,
                               max_grid_deviation)
    # No order_corners here: the flow cannot mirror the grid, and a grid turned by 180 degrees
    # on a board whose ends differ puts every square on the wrong colour, which the square
    # check below refuses (on a board whose ends look alike nothing can tell, as in detection).
    # The saddles and squares are sampled through the flow's homography, not one fitted
    # again: its corners are within the flow's error (a fraction of a pixel) of the refined
    # ones, and every sample is a fifth of a square or more from a corner.
    saddle = _saddle_ok(gray, H, corners, grid, border_ok=True)
    if not saddle.all():
        # A hand over corners, which stay where they were put and agree with their
        # neighbours: those without the chessboard's saddle go, the others are checked as a
        # partly hidden board's (the squares they bound).
        return _partial_without(gray, corners, saddle, grid, board, sc, max_grid_deviation,
                                consistent=True)
    if not board_squares_pattern_ok(gray, H, board, MIN_PATTERN_CONTRAST):
        # A hand over squares only: the partial checks decide.
        return _follow_partial(gray, corners, np.ones(len(corners), bool), grid, board,
                               subpix_window_px, sc, max_grid_deviation, "partial")
    return corners, "tracked"


# Shrunk copies of the last few images: a frame shrunk for the flow into it serves again for
# the flow out of it. Keyed by the image object itself (held here, so its id is not reused).
_SHRUNK: list = []


def _shrunk(gray: np.ndarray, f: int) -> np.ndarray:
    """``gray`` shrunk by the integer factor ``f`` (area average), from a small cache.

    A power of two is halved repeatedly: OpenCV's area resize by 1/2 is ~8x faster than by
    1/4 (0.12 against 0.95 ms for a 1080x1920 frame), and two 2x2 averages are the 4x4
    average (up to the rounding of the half-size image to 8 bits).
    """
    for image, k, small in _SHRUNK:
        if image is gray and k == f:
            return small
    if f > 2 and f % 2 == 0:
        small = cv2.resize(_shrunk(gray, f // 2), None, fx=0.5, fy=0.5,
                           interpolation=cv2.INTER_AREA)
    else:
        small = cv2.resize(gray, None, fx=1.0 / f, fy=1.0 / f, interpolation=cv2.INTER_AREA)
    _SHRUNK.append((gray, f, small))
    del _SHRUNK[:-6]  # the last three images, at up to two factors each
    return small


# Tracked frames with some corners hidden (a hand; the image border) that keep the rest.
PARTIAL_METHODS = ("partial", "out_of_view")


# The search backs off while the board stays lost: it runs on the 1st, 4th, 8th and 16th frame
# after the loss, then every SEARCH_EVERY_MAX frames (a board that comes back is found within
# that many frames and the frames before it are tracked backwards, so searching more often buys
# only an earlier answer; the 8th catches the board as a passing hand leaves it, which the
# searches from the 16th on can miss for seconds; the frames right after the tracker lost a
# board are searched by ``_relocate``). A quick search that finds nothing costs about six
# frames' decoding (4.5 ms at 640x480, 11 ms at 1280x720 on a partly hidden board), so every
# 16 frames it costs under 0.4 of the decoding while the board is lost (every 8: 0.75).
SEARCH_EVERY_MAX = 16
# ... and the full detector (on the image shrunk to DETECT_LONG_SIDE_PX) on the 64th frame
# after the loss and every DEEP_SEARCH_EVERY frames after (and on the frames right after the
# tracker lost one, ``_relocate``). Not on the first frame of a session or restart: there the
# quick search misses mostly boards that are not there (a hand, the border; ~220 ms per
# 1280x720 frame for nothing on the realistic renders), and a whole board it misses is found
# later and tracked back. It costs about 40 to 50 frames' decoding (77 ms at 1280x720, 100 ms
# at 1080x1920): from the 64th frame and every 128th, at most 0.7 of the decoding while the
# board is lost. It finds the boards the quick search cannot see: small squares before the
# first view of the board (after it, the quick search runs at the scale the squares need) and
# poor contrast.
DEEP_SEARCH_FIRST = 64
DEEP_SEARCH_EVERY = 128
# Most grey-image bytes kept waiting for a board (memory does not grow with the session:
# 80 frames at 1920x1080, 540 at 640x480, more than DEEP_SEARCH_FIRST); older waiting frames
# are decided without it.
MAX_PENDING_BYTES = 160 * 2**20


def _hand_hidden(corners_px, method):
    """The corners a hand hid in a frame followed as ``"partial"`` (for ``track_corners``'
    ``hidden``), else None."""
    if method != "partial" or corners_px is None:
        return None
    return ~np.isfinite(corners_px).all(axis=1)


class _CornerFollower:
    """extract_corners' per-frame decisions: track, search quickly (backing off), or detect.

    ``push`` takes frames in order and returns the ``(frame, t_s, corners_px or None,
    method)`` results that are decided, in frame order; ``finish`` returns the rest.
    Frames without a board are ``"not_found"`` when a detector looked at them and
    ``"not_searched"`` when the search's back-off skipped them (and no board could be
    tracked into them from a later frame).
    """

    def __init__(self, board, subpix_window_px, max_grid_deviation, max_gap, flags, track,
                 restart_every, keep_partial=True):
        self.keep_partial = keep_partial
        self.board = board
        self.subpix = subpix_window_px
        self.max_dev = max_grid_deviation
        self.max_gap = max_gap
        self.flags = flags
        self.track = track
        self.restart_every = restart_every
        self.pending = collections.deque()  # (frame, t_s, gray, searched) waiting for a board
        self.pending_bytes = 0
        self.cv_errors = 0  # OpenCV calls that raised (the frame went on without them)
        self.n_predicted = 0  # frames followed by ``predict_corners``
        self._reset()

    def _guard(self, fn, fail_method, frame, *args):
        """``fn(*args)``; a cv2.error becomes ``(None, fail_method)``, logged and counted."""
        try:
            return fn(*args)
        except cv2.error as exc:
            self.cv_errors += 1
            log.warning("corners: frame %d: OpenCV failed in %s (%s); the frame goes on "
                        "without it", frame, fn.__name__, str(exc).strip().splitlines()[-1])
            return None, fail_method

    def _reset(self):
        # (gray, corners_px, frame, hidden) of the last frame the board was followed; hidden:
        # the corners a hand hid there (``track_corners``), None unless it was partial.
        self.state = None
        self.last_found = None  # (corners_px, frame): continuity for detect_corners
        self.lost_for = 0  # frames since the board was last followed (the search's back-off)
        self.spacing = 0.0  # median square size (px) of the board when last followed
        # (frame, t_s, corners_px) of the last two frames the board was followed in, for
        # ``predict_corners``.
        self.history = collections.deque(maxlen=2)

    def _search_now(self) -> bool:
        n = self.lost_for
        return n in (1, 4, 8) or n % SEARCH_EVERY_MAX == 0

    def _quick_scale(self):
        """Shrink factor of the quick search: squares of the last board >= QUICK_MIN_SQUARE_PX,
        at full size for boards whose squares are under twice that (a board of 8-15 px
        squares, which only the full detector found at half size)."""
        if self.spacing <= 0:
            return None
        return float(np.clip(QUICK_MIN_SQUARE_PX / self.spacing, 0.25, 1.0))

    def push(self, frame, t_s, gray):
        out = []
        if self.restart_every and frame % self.restart_every == 0:
            out += self.finish()
            self._reset()
        if not self.track:
            out.append(self._detect(frame, t_s, gray))
            return out
        if self.state is not None and frame - self.state[2] <= self.max_gap:
            out.append(self._track(frame, t_s, gray, self.state))
            return out
        self.lost_for += 1
        if not self._search_now():
            self._wait(frame, t_s, gray, False, out)
            return out
        corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                         self.board, self.subpix, self.max_dev,
                                         self._quick_scale())
        if corners_px is None and (self.lost_for == DEEP_SEARCH_FIRST
                                   or self.lost_for % DEEP_SEARCH_EVERY == 0):
            # Now and then the full detector (on the shrunk image), for the whole boards the
            # quick one misses (low contrast, small squares).
            prev = self.flags if self.flags is not None else VIDEO_SEARCH_FLAGS
            corners_px, method = self._guard(detect_corners, "cv_error", frame, gray,
                                             self.board, self.subpix, None, prev,
                                             self.max_dev, False, self.keep_partial)
        if corners_px is None:
            self._wait(frame, t_s, gray, True, out)
            return out
        out += self._track_back(gray, corners_px, frame, t_s, method)
        self._keep(gray, corners_px, frame, found=True, method=method, t_s=t_s)
        out.append((frame, t_s, corners_px, method))
        return out

    def push_undecodable(self, frame, t_s):
        """A frame the decoder refused: the board is not followed across it (the waiting
        frames are decided as at the end of a take, and the search starts afresh)."""
        out = self.finish()
        self._reset()
        out.append((frame, t_s, None, "undecodable"))
        return out

    def _wait(self, frame, t_s, gray, searched, out):
        """Keep a frame for tracking backwards; decide the oldest beyond the memory bound."""
        self.pending.append((frame, t_s, gray, searched))
        self.pending_bytes += gray.nbytes
        while self.pending_bytes > MAX_PENDING_BYTES and len(self.pending) > 1:
            out.append(self._undecided(*self.pending.popleft()))

    def _undecided(self, frame, t_s, gray, searched):
        self.pending_bytes -= gray.nbytes
        return frame, t_s, None, "not_found" if searched else "not_searched"

    def finish(self):
        """Decide the frames still waiting: the last one is searched (if the back-off skipped
        it; then, if the quick search fails, with the full detector) and the others tracked
        back from it; else no board was found to track from."""
        if self.pending and not self.pending[-1][3]:
            frame, t_s, gray, _ = self.pending.pop()
            self.pending_bytes -= gray.nbytes
            corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                             self.board, self.subpix, self.max_dev,
                                             self._quick_scale())
            if corners_px is None:
                # A board the quick search misses (a hand over it from the start, low
                # contrast) in a take, or a piece before a restart, shorter than
                # DEEP_SEARCH_EVERY frames: the full detector once, on the shrunk image.
                corners_px, method = self._guard(detect_corners, "cv_error", frame, gray,
                                                 self.board, self.subpix, None,
                                                 self.flags or VIDEO_SEARCH_FLAGS,
                                                 self.max_dev, False, self.keep_partial)
            if corners_px is not None:
                return self._track_back(gray, corners_px, frame, t_s, method) + [
                    (frame, t_s, corners_px, method)]
            self.pending.append((frame, t_s, gray, True))
            self.pending_bytes += gray.nbytes
        out = [self._undecided(*p) for p in self.pending]
        self.pending.clear()
        self.pending_bytes = 0
        return out

    def _keep(self, gray, corners_px, frame, found, method=None, t_s=None):
        self.state = (gray, corners_px, frame, _hand_hidden(corners_px, method))
        self.history.append((frame, t_s, corners_px))
        self.lost_for = 0
        self.spacing = _median_spacing(corners_px, self.board) or self.spacing
        if found:
            self.last_found = (corners_px, frame)

    def _predicted(self, frame, t_s, gray, history, step):
        """``predict_corners`` where ``history`` holds the board's corners in the two frames
        before this one in the direction of travel (``step``: +1 forwards, -1 when tracking
        backwards), else (None, "changed")."""
        if len(history) < 2:
            return None, "changed"
        (f2, t2, px2), (f1, t1, px1) = history
        if f1 != frame - step or f2 != frame - 2 * step or t1 == t2:
            return None, "changed"
        return self._guard(predict_corners, "changed", frame, gray, px1, px2,
                           (t_s - t1) / (t1 - t2), self.board, self.subpix, self.max_dev)

    def _track(self, frame, t_s, gray, ref):
        corners_px, method = self._predicted(frame, t_s, gray, self.history, 1)
        if corners_px is not None:
            self.n_predicted += 1
            self._keep(gray, corners_px, frame, found=method == "tracked", method=method,
                       t_s=t_s)
            return frame, t_s, self._published(corners_px, method), method
        corners_px, method = self._guard(
            track_corners, "lost", frame, ref[0], gray, ref[1], self.board, self.subpix,
            self.max_dev, ref[3]
        )
        if method == "lost":
            return self._relocate(frame, t_s, gray)
        self._keep(gray, corners_px, frame, found=method == "tracked", method=method, t_s=t_s)
        return frame, t_s, self._published(corners_px, method), method

    def _relocate(self, frame, t_s, gray):
        """A frame the tracker lost the board in (at most ``max_gap`` frames after it was
        followed): the quick search, then the detector on the image shrunk to
        DETECT_LONG_SIDE_PX (the board is likely still there)."""
        self.lost_for += 1
        corners_px, method = self._guard(quick_detect_corners, "not_found", frame, gray,
                                         self.board, self.subpix, self.max_dev,
                                         self._quick_scale())
        if corners_px is None:
            return self._detect(frame, t_s, gray, full_size=False)
        self._keep(gray, corners_px, frame, found=True, t_s=t_s)
        return frame, t_s, corners_px, method

    def _published(self, corners_px, method):
        """The corners a tracked frame puts in the table (None: not found)."""
        if method == "tracked" or (self.keep_partial and method in PARTIAL_METHODS):
            return corners_px
        return None

    def _detect(self, frame, t_s, gray, full_size=True):
        prev = None
        if self.last_found is not None and frame - self.last_found[1] <= self.max_gap:
            prev = self.last_found[0]
        flags = self.flags
        if flags is None:
            flags = VIDEO_FIND_FLAGS if prev is not None else VIDEO_SEARCH_FLAGS
        corners_px, method = self._guard(detect_corners, "cv_error", frame, gray, self.board,
                                         self.subpix, prev, flags, self.max_dev, full_size,
                                         self.keep_partial)
        if corners_px is not None:
            self._keep(gray, corners_px, frame, found=True, method=method, t_s=t_s)
        return frame, t_s, corners_px, method

    def _track_back(self, gray, corners_px, frame, t_s, found_by=None):
        """Results of the waiting frames, tracked backwards from a frame with the board (found
        by the method ``found_by``); where that fails, the detector once (the board may have been whole
        there), then nothing."""
        pending, self.pending = list(self.pending), collections.deque()
        self.pending_bytes = 0
        ref = (gray, corners_px, frame, _hand_hidden(corners_px, found_by))
        history = collections.deque([(frame, t_s, corners_px)], maxlen=2)
        out = []
        tried_detect = False
        for f, t_s, g, searched in reversed(pending):
            result = None
            if ref[2] - f <= self.max_gap:
                px, method = self._predicted(f, t_s, g, history, -1)
                if px is not None:
                    self.n_predicted += 1
                else:
                    px, method = self._guard(track_corners, "lost", f, ref[0], g, ref[1],
                                             self.board, self.subpix, self.max_dev, ref[3])
                if method != "lost":
                    ref = (g, px, f, _hand_hidden(px, method))
                    history.append((f, t_s, px))
                    result = (f, t_s, self._published(px, method), method + "_back")
                elif not tried_detect:
                    tried_detect = True
                    px, method = self._guard(detect_corners, "cv_error", f, g, self.board,
                                             self.subpix, None,
                                             self.flags or VIDEO_SEARCH_FLAGS, self.max_dev,
                                             False, self.keep_partial)
                    if px is not None:
                        ref = (g, px, f, _hand_hidden(px, method))
                        history.append((f, t_s, px))
                    result = (f, t_s, px, method)
            if result is None:
                result = (f, t_s, None, "not_found" if searched else "not_searched")
            out.append(result)
        return out[::-1]
