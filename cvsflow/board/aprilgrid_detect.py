"""An AprilGrid in an image: checked tag ids, sub-pixel corners, and the corners table of a video.

:func:`detect_aprilgrid` takes the raw tags of :func:`cvsflow.board.aprilgrid_tags.detect_tags`,
keeps only those that are tags of this grid with their right ids and corner order
(:func:`consistent_tags`), refines each corner on its X junction with ``cv2.cornerSubPix`` in a
window that stays inside the tag's black border and the gap (:func:`refine_tag_corners`), and
drops corners the refinement did not lock on to (:func:`corner_contrast_ok`,
:func:`local_deviation_px`). A partly seen grid keeps its true ids; a mirrored image, a tag of
another grid or family, a turned or repeated tag gives nothing wrong: no flipped or mislabelled
corner is ever kept (the tests check each case on rendered truth).

:func:`find_aprilgrid` serves the calibration's stills and :func:`extract_aprilgrid_corners`
the corners stage (every frame detected on its own: the tags name the corners).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable

import cv2
import numpy as np
import pandas as pd

from cvsflow.board.aprilgrid import MIN_TAGS, AprilGrid, aprilgrid_from_board
from cvsflow.board.aprilgrid_tags import default_passes, detect_tags, passes_name
from cvsflow.board.model import SUBPIX_CRITERIA, CornerRows
from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)

#: RANSAC threshold of the consistency homography, as a share of the median tag side in px.
#: A tag with a wrong id is a pitch (1 + tag_spacing sides) away, a turned one a side away.
HOMOGRAPHY_RANSAC_SIDES = 0.25
#: cornerSubPix half window, in bits of the tag as seen in the image, clipped to
#: [MIN_SUBPIX_WINDOW_PX, MAX_SUBPIX_WINDOW_PX] and kept a quarter bit inside the black border
#: and the gap. On renders the median (p95) corner error was 0.121 (0.766) px with Kalibr's
#: fixed 2 px, 0.055 (0.278) with 1 bit, 0.034 (0.096) with 1.5 and 0.030 (0.092) with 1.75.
SUBPIX_WINDOW_BITS = 1.75
MIN_SUBPIX_WINDOW_PX = 2
MAX_SUBPIX_WINDOW_PX = 15
#: A refined corner further than this from the detector's corner is dropped (px, and in bits of
#: the tag: the larger applies). ArUco's raw corners are often 2-3 px off; half a bit dropped 42 %
#: of them, one bit keeps them at the same accuracy. Kalibr's own limit is sqrt(1.5) = 1.22 px.
MAX_SUBPIX_SHIFT_PX = 2.0
MAX_SUBPIX_SHIFT_BITS = 1.0
#: Corner check: samples at these distances (bits, along both of the tag's edges) from the
#: corner, in the tag's quadrant (its black border: dark), in the corner square's quadrant
#: (dark) and in the two gap quadrants (light).
CORNER_SAMPLE_BITS = (0.6, 1.2)
#: The lightest dark sample and the darkest light one must differ by this share of the frame's
#: contrast (median light minus median dark) and by MIN_CORNER_CONTRAST grey levels.
CORNER_CONTRAST_FRAC = 0.4
MIN_CORNER_CONTRAST = 10.0
#: A refined corner further than this from where the homography through its neighbouring tags'
#: corners puts it is dropped (bits of its tag, and px: the larger applies).
MAX_LOCAL_DEVIATION_BITS = 0.3
MIN_LOCAL_DEVIATION_PX = 1.0


def _signed_area(quads: np.ndarray) -> np.ndarray:
    """Shoelace area of quads (T, 4, 2) in the order given; negative: clockwise on screen
    (image y down) when the points go counter-clockwise in a y-up frame."""
    x, y = quads[..., 0], quads[..., 1]
    return 0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)


def _apply_h(H: np.ndarray, xy: np.ndarray) -> np.ndarray:
    p = xy @ H[:, :2].T + H[:, 2]
    return p[..., :2] / p[..., 2:3]


def _sides_px(quads: np.ndarray) -> np.ndarray:
    """(T, 4) lengths of each quad's sides, px."""
    return np.linalg.norm(quads - np.roll(quads, -1, axis=-2), axis=-1)


def consistent_tags(tag_ids: np.ndarray, corners_px: np.ndarray, grid: AprilGrid,
                    min_tags: int = MIN_TAGS, stats: dict | None = None) -> np.ndarray:
    """Which raw detections are tags of this grid, with their right ids and corner order.

    A detection is kept when (in this order):

    1. its id is one of the grid's (``0 <= id < n_tags``) and appears once in the frame (or,
       for a repeated id, it is the only one of its copies that passes 4);
    2. its corners, in Kalibr's order, wind clockwise on screen (the order of a tag seen from
       its printed face) round a quad whose sides are all longer than 2 px;
    3. the grid is seen from its printed face: the homography from B to the image fitted
       (RANSAC) through the corners of all the tags of steps 1-2 reverses orientation;
    4. through that homography, the detection's centre is nearer to its own tag's predicted
       centre than to any other tag's, and each of its corners is nearer to its own predicted
       corner than to the tag's three others (no wrong id, no turned or mirrored tag).

    Step 4 compares with the nearest alternative only, so lens distortion up to about half a
    tag pitch in the homography's residuals does not drop a good tag. If fewer than
    ``min_tags`` detections are left, none is kept.

    Parameters
    ----------
    tag_ids : ndarray, shape (T,), int
    corners_px : ndarray, shape (T, 4, 2), float
        Kalibr's corner order, distorted pixels.
    grid : AprilGrid
    min_tags : int
        Fewest tags for a frame, >= 3.
    stats : dict, optional
        Filled with the number of detections dropped at each step (``not_in_grid``,
        ``duplicate``, ``winding``, ``mirrored``, ``off_grid``, ``too_few``: fewer than
        ``min_tags`` were left) and ``kept``.

    Returns
    -------
    keep : ndarray, shape (T,), bool
    """
    if min_tags < 3:
        raise ValueError(f"min_tags={min_tags}; expected >= 3 (the consistency check needs them)")
    tag_ids = np.asarray(tag_ids, dtype=np.int64)
    corners_px = np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2)
    counts = dict.fromkeys(("not_in_grid", "duplicate", "winding", "mirrored", "off_grid", "too_few"), 0)
    keep = (tag_ids >= 0) & (tag_ids < grid.n_tags)
    counts["not_in_grid"] = int((~keep).sum())
    sides = _sides_px(corners_px)
    good_shape = (_signed_area(corners_px) < 0) & (sides.min(axis=1, initial=np.inf) > 2.0)
    counts["winding"] = int((keep & ~good_shape).sum())
    keep &= good_shape
    ids_kept, n_copies = np.unique(tag_ids[keep], return_counts=True)
    repeated = np.isin(tag_ids, ids_kept[n_copies > 1]) & keep
    fit = keep & ~repeated
    H = None
    if fit.sum() >= min_tags:
        p_B = grid.object_points()[:, :2].reshape(grid.n_tags, 4, 2)
        H, _ = cv2.findHomography(p_B[tag_ids[fit]].reshape(-1, 2), corners_px[fit].reshape(-1, 2),
                                  cv2.RANSAC, HOMOGRAPHY_RANSAC_SIDES * float(np.median(sides[fit])),
                                  maxIters=2000, confidence=0.999)
    if fit.sum() < min_tags:
        counts["too_few"] = int(keep.sum())
        keep[:] = False
    elif H is None:
        counts["off_grid"] = int(keep.sum())
        keep[:] = False
    elif _orientation_sign(H, grid) > 0:
        counts["mirrored"] = int(keep.sum())
        keep[:] = False
    else:
        on_grid = _on_grid(H, grid, tag_ids, corners_px, p_B) & keep
        counts["off_grid"] = int((keep & ~repeated & ~on_grid).sum())
        for tag in ids_kept[n_copies > 1]:
            copies = np.flatnonzero((tag_ids == tag) & keep)
            good = copies[on_grid[copies]]
            counts["duplicate"] += len(copies) - (len(good) == 1)
            on_grid[copies] = False
            if len(good) == 1:
                on_grid[good] = True
        keep = on_grid
        if keep.sum() < min_tags:
            counts["too_few"] = int(keep.sum())
            keep[:] = False
    counts["kept"] = int(keep.sum())
    if stats is not None:
        stats.update(counts)
    return keep


def _orientation_sign(H: np.ndarray, grid: AprilGrid) -> float:
    """Sign of the Jacobian determinant of the homography B -> image at the grid's centre:
    negative when the printed face is seen (B's y up becomes the image's y down)."""
    c = grid.tag_centres()[:, :2].mean(axis=0)
    w = H[2, 0] * c[0] + H[2, 1] * c[1] + H[2, 2]
    u = _apply_h(H, c[None])[0]
    J = (H[:2, :2] - np.outer(u, H[2, :2])) / w
    return float(np.sign(np.linalg.det(J)))


def _on_grid(H, grid, tag_ids, corners_px, p_B) -> np.ndarray:
    """Step 4 of :func:`consistent_tags`: (T,) bool."""
    predicted = _apply_h(H, p_B.reshape(-1, 2)).reshape(grid.n_tags, 4, 2)
    ok = np.zeros(len(tag_ids), dtype=bool)
    if not np.isfinite(predicted).all():
        return ok
    centres = predicted.mean(axis=1)
    for i, (tag, quad) in enumerate(zip(tag_ids, corners_px, strict=True)):
        if not 0 <= tag < grid.n_tags:
            continue
        nearest_tag = np.argmin(np.linalg.norm(centres - quad.mean(axis=0), axis=1))
        d = np.linalg.norm(quad[:, None, :] - predicted[tag][None, :, :], axis=-1)  # (k, k')
        ok[i] = nearest_tag == tag and np.array_equal(np.argmin(d, axis=1), np.arange(4))
    return ok


def subpix_window_px(corners_px: np.ndarray, grid: AprilGrid,
                     window_bits: float = SUBPIX_WINDOW_BITS) -> np.ndarray:
    """cornerSubPix half window of each tag, from its shortest side in the image.

    Parameters
    ----------
    corners_px : ndarray, shape (T, 4, 2)
        The tags' detected corners, px.
    grid : AprilGrid
    window_bits : float
        Half window in bits of the tag (its shortest side / ``tag_bits``); kept a quarter bit
        inside the black border (``border_bits``) and the gap, so that the window sees the X
        junction only.

    Returns
    -------
    half_window_px : ndarray, shape (T,), int
    """
    gap_bits = grid.tag_spacing * grid.tag_bits
    bits = min(window_bits, grid.border_bits - 0.25, gap_bits - 0.25)
    w = np.floor(bits * _sides_px(corners_px).min(axis=1) / grid.tag_bits)
    return np.clip(w, MIN_SUBPIX_WINDOW_PX, MAX_SUBPIX_WINDOW_PX).astype(int)


def refine_tag_corners(gray: np.ndarray, corners_px: np.ndarray, grid: AprilGrid,
                       window_bits: float = SUBPIX_WINDOW_BITS) -> np.ndarray:
    """Sub-pixel corners of checked tags (cv2.cornerSubPix on each tag corner's X junction).

    A corner is dropped (NaN) when its window does not fit in the image; when cornerSubPix
    leaves it where it was (its window has no gradient: the detector's corner was off the
    junction; on the yac frames a plain move limit kept such corners 4-7 px off); when it
    moves further than ``max(MAX_SUBPIX_SHIFT_PX, MAX_SUBPIX_SHIFT_BITS bits)``; or when the
    refined corner does not show the tag's corner (:func:`corner_contrast_ok`).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (T, 4, 2)
        Kalibr's corner order, distorted pixels.
    grid : AprilGrid
    window_bits : float
        Half window in bits (:func:`subpix_window_px`).

    Returns
    -------
    refined_px : ndarray, shape (T, 4, 2), float64
        NaN for the corners dropped.
    """
    corners_px = np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2)
    refined = np.full_like(corners_px, np.nan)
    height, width = gray.shape
    windows = subpix_window_px(corners_px, grid, window_bits)
    bits_px = _sides_px(corners_px).min(axis=1) / grid.tag_bits
    for w in np.unique(windows):
        tags = np.flatnonzero(windows == w)
        quads = corners_px[tags].reshape(-1, 2)
        inside = ((quads[:, 0] >= w + 1) & (quads[:, 0] <= width - w - 2)
                  & (quads[:, 1] >= w + 1) & (quads[:, 1] <= height - w - 2))
        if not inside.any():
            continue
        start = quads[inside].astype(np.float32).reshape(-1, 1, 2)
        out = cv2.cornerSubPix(gray, start.copy(), (int(w), int(w)), (-1, -1), SUBPIX_CRITERIA)
        result = np.full((len(quads), 2), np.nan)
        result[inside] = out.reshape(-1, 2)
        moved = np.linalg.norm(result - quads, axis=1)
        limit = np.maximum(MAX_SUBPIX_SHIFT_PX, MAX_SUBPIX_SHIFT_BITS * np.repeat(bits_px[tags], 4))
        stuck = np.zeros(len(quads), dtype=bool)
        stuck[inside] = np.all(out.reshape(-1, 2) == start.reshape(-1, 2), axis=1)
        result[~(moved <= limit) | stuck] = np.nan
        refined[tags] = result.reshape(-1, 4, 2)
    refined[~corner_contrast_ok(gray, refined, corners_px, grid)] = np.nan
    return refined


def corner_contrast_ok(gray: np.ndarray, corners_px: np.ndarray, quads_px: np.ndarray,
                       grid: AprilGrid) -> np.ndarray:
    """Which corners look like a tag corner: the dark tag and corner square between two light gaps.

    Around corner k of a tag, with e1, e2 the image vectors of one bit along its two edges
    (from the detected quad), the points ``c + a e1 + b e2`` with a, b in
    ``CORNER_SAMPLE_BITS`` lie on the tag's black border, ``c - a e1 - b e2`` on the black
    corner square diagonally outside, ``c + a e1 - b e2`` and ``c - a e1 + b e2`` in the white
    gaps beside it. A corner whose corner square is covered (a motion-capture marker stuck on
    it, as on the yac target's four outer corners, pulls cornerSubPix 2-5 px off) fails.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (T, 4, 2)
        Corners to check, px (NaN: skipped, returned False).
    quads_px : ndarray, shape (T, 4, 2)
        The tags' detected corners, for the edge directions and the bit length, px.
    grid : AprilGrid

    Returns
    -------
    ok : ndarray, shape (T, 4), bool
    """
    corners_px = np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2)
    quads_px = np.asarray(quads_px, dtype=np.float64).reshape(-1, 4, 2)
    if not len(corners_px):
        return np.zeros((0, 4), dtype=bool)
    e1 = (np.roll(quads_px, -1, axis=1) - quads_px) / grid.tag_bits  # to the next corner
    e2 = (np.roll(quads_px, 1, axis=1) - quads_px) / grid.tag_bits  # to the previous one
    a, b = (v.ravel()[:, None] for v in np.meshgrid(CORNER_SAMPLE_BITS, CORNER_SAMPLE_BITS))
    c, E1, E2 = corners_px[:, :, None, :], e1[:, :, None, :], e2[:, :, None, :]
    dark = _sample(gray, np.concatenate([c + a * E1 + b * E2, c - a * E1 - b * E2], axis=2))
    light = _sample(gray, np.concatenate([c + a * E1 - b * E2, c - a * E1 + b * E2], axis=2))
    finite = (np.isfinite(corners_px).all(axis=-1) & np.isfinite(dark).all(axis=-1)
              & np.isfinite(light).all(axis=-1))
    if not finite.any():
        return finite
    contrast = float(np.median(light[finite]) - np.median(dark[finite]))
    need = max(MIN_CORNER_CONTRAST, CORNER_CONTRAST_FRAC * contrast)
    with np.errstate(invalid="ignore"):
        step = np.min(light, axis=-1) - np.max(dark, axis=-1)
    return finite & (step >= need)


def _sample(gray: np.ndarray, points_px: np.ndarray) -> np.ndarray:
    """Grey levels of a 3x3-blurred image at points (..., 2), bilinear; NaN outside the image."""
    smooth = cv2.blur(gray, (3, 3)).astype(np.float32)
    q = np.nan_to_num(points_px, nan=-1e4).astype(np.float32)
    return cv2.remap(smooth, q[..., 0].reshape(1, -1), q[..., 1].reshape(1, -1), cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan).reshape(points_px.shape[:-1])


def local_deviation_px(corners_px: np.ndarray, tag_ids: np.ndarray, grid: AprilGrid) -> np.ndarray:
    """Distance of each corner from its prediction by the neighbouring tags' corners.

    For each tag, a homography B -> image is fitted (RANSAC, 1 px) through the corners of the
    tags round it (grid distance 1, the tag itself left out; 2 if that gives fewer than 3
    tags) and its own corners are predicted. Over so small a patch lens distortion barely
    bends the grid, so a corner the refinement pulled off its junction stands out.

    Parameters
    ----------
    corners_px : ndarray, shape (T, 4, 2)
        Refined corners, px, NaN where dropped.
    tag_ids : ndarray, shape (T,), int
        Their (checked) tag ids.
    grid : AprilGrid

    Returns
    -------
    deviation_px : ndarray, shape (T, 4)
        NaN where the corner is NaN or its tag has fewer than 3 neighbouring tags.
    """
    corners_px = np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2)
    tag_ids = np.asarray(tag_ids, dtype=np.int64)
    p_B = grid.object_points()[:, :2].reshape(grid.n_tags, 4, 2)
    col, row = tag_ids % grid.tag_cols, tag_ids // grid.tag_cols
    out = np.full(corners_px.shape[:2], np.nan)
    for i in range(len(tag_ids)):
        cheb = np.maximum(np.abs(col - col[i]), np.abs(row - row[i]))
        for reach in (1, 2):
            near = (cheb > 0) & (cheb <= reach)
            if near.sum() >= 3:
                break
        else:
            continue
        src = p_B[tag_ids[near]].reshape(-1, 2)
        dst = corners_px[near].reshape(-1, 2)
        ok = np.isfinite(dst).all(axis=1)
        if ok.sum() < 8:
            continue
        H, _ = cv2.findHomography(src[ok], dst[ok], cv2.RANSAC, 1.0)
        if H is not None:
            out[i] = np.linalg.norm(corners_px[i] - _apply_h(H, p_B[tag_ids[i]]), axis=1)
    return out


def refine_and_check(gray: np.ndarray, tag_ids: np.ndarray, corners_px: np.ndarray, grid: AprilGrid,
                     window_bits: float = SUBPIX_WINDOW_BITS, stats: dict | None = None) -> np.ndarray:
    """Refine checked tags' corners and drop those off their neighbours' grid.

    :func:`refine_tag_corners`, then :func:`local_deviation_px`: a corner further than
    ``max(MIN_LOCAL_DEVIATION_PX, MAX_LOCAL_DEVIATION_BITS bits)`` from its prediction is
    dropped.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    tag_ids : ndarray, shape (T,), int
        Tags kept by :func:`consistent_tags`.
    corners_px : ndarray, shape (T, 4, 2)
        Their detected corners, Kalibr's order, distorted pixels.
    grid : AprilGrid
    window_bits : float
        cornerSubPix half window in bits of the tag.
    stats : dict, optional
        Filled with ``corners_off_grid``.

    Returns
    -------
    refined_px : ndarray, shape (T, 4, 2), float64
        NaN for the corners dropped.
    """
    quads_px = np.asarray(corners_px, dtype=np.float64).reshape(-1, 4, 2)
    refined = refine_tag_corners(gray, quads_px, grid, window_bits)
    deviation = local_deviation_px(refined, tag_ids, grid)
    bit_px = _sides_px(quads_px).min(axis=1) / grid.tag_bits
    limit = np.maximum(MIN_LOCAL_DEVIATION_PX, MAX_LOCAL_DEVIATION_BITS * bit_px)[:, None]
    with np.errstate(invalid="ignore"):
        off = deviation > limit
    refined[off] = np.nan
    if stats is not None:
        stats["corners_off_grid"] = int(off.sum())
    return refined


def detect_aprilgrid(gray: np.ndarray, grid: AprilGrid, passes: tuple | None = None,
                     min_tags: int = MIN_TAGS, refine: bool = True,
                     window_bits: float = SUBPIX_WINDOW_BITS, stats: dict | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """AprilGrid corners of one frame: checked ids, sub-pixel pixels.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    grid : AprilGrid
    passes : tuple of AprilTagPass or ArucoPass, optional
        Tag detector runs, merged (:func:`cvsflow.board.aprilgrid_tags.detect_tags`); default
        :func:`cvsflow.board.aprilgrid_tags.default_passes`.
    min_tags : int
        Fewest consistent tags for a frame (Kalibr: 4); with fewer, nothing is returned.
    refine : bool
        Refine and check the corners (:func:`refine_and_check`); False returns the detector's
        corners of the consistent tags.
    window_bits : float
        cornerSubPix half window in bits of the tag.
    stats : dict, optional
        Filled with the counts of :func:`consistent_tags`, ``detected`` (raw detections),
        ``corners_off_grid`` (refined corners :func:`local_deviation_px` puts off their
        neighbours' grid) and ``corners_dropped`` (every corner of a kept tag not returned).

    Returns
    -------
    ids : ndarray, shape (M,), int64
        Corner ids ``4 * tag + k``, increasing; a partly seen grid keeps its true ids.
    uv_px : ndarray, shape (M, 2), float64
        Distorted pixels of those corners (pixel centres at integers, as cv2).

    Raises
    ------
    ValueError
        ``gray`` is not a 2-D uint8 image.
    """
    gray = np.asarray(gray)
    if gray.ndim != 2 or gray.dtype != np.uint8:
        raise ValueError(f"gray: expected a (H, W) uint8 image, got {gray.shape} {gray.dtype}")
    tag_ids, corners_px = detect_tags(gray, grid, passes)
    counts: dict = {"detected": len(tag_ids)}
    keep = consistent_tags(tag_ids, corners_px, grid, min_tags, stats=counts)
    tag_ids, corners_px = tag_ids[keep], corners_px[keep]
    if refine and len(tag_ids):
        corners_px = refine_and_check(gray, tag_ids, corners_px, grid, window_bits, stats=counts)
    ids = (4 * tag_ids[:, None] + np.arange(4)).ravel()
    uv_px = corners_px.reshape(-1, 2)
    found = np.isfinite(uv_px).all(axis=1)
    counts["corners_dropped"] = int((~found).sum())
    if stats is not None:
        stats.update(counts)
    order = np.argsort(ids[found], kind="stable")
    return ids[found][order], uv_px[found][order]


def find_aprilgrid(gray: np.ndarray, board: dict, passes: tuple | None = None):
    """AprilGrid corners of a calibration still, or None (``cvsflow.calibration``).

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    board : dict
        A ``type: aprilgrid`` board (:func:`cvsflow.board.aprilgrid.aprilgrid_from_board`).
    passes : tuple of AprilTagPass or ArucoPass, optional
        Default :func:`cvsflow.board.aprilgrid_tags.default_passes`.

    Returns
    -------
    (ids, corners_px) or None
        ``ids`` (M,) int64 ascending corner ids, ``corners_px`` (M, 2) float64 pixels; None
        with fewer than ``MIN_TAGS`` consistent tags.
    """
    ids, uv_px = detect_aprilgrid(gray, aprilgrid_from_board(board), passes)
    return (ids, uv_px) if len(ids) else None


def extract_aprilgrid_corners(frames: Iterable[tuple[int, float, np.ndarray]], board: dict,
                              n_frames: int | None = None, log_every: int = 300,
                              passes: tuple | None = None) -> pd.DataFrame:
    """AprilGrid corners of every video frame: the corners table of ``cvsflow.corners.extract_corners``.

    Every frame is detected on its own (the tags name the corners, so nothing is tracked and a
    video cut into chunks gives the table of one pass).

    Parameters
    ----------
    frames : iterable of (int, float, ndarray)
        ``(frame, t_s, gray)``: frame index, video time (s), 8-bit grayscale image (H, W);
        ``gray`` None for a frame the decoder refused.
    board : dict
        A ``type: aprilgrid`` board.
    n_frames : int, optional
        Frames expected, for progress messages only.
    log_every : int
        Log progress every this many frames.
    passes : tuple of AprilTagPass or ArucoPass, optional
        Default :func:`cvsflow.board.aprilgrid_tags.default_passes`.

    Returns
    -------
    corners : DataFrame
        ``frame, t_s, found, corner, u_px, v_px`` (docs/contracts.md corners.parquet): a found
        frame has one row per corner kept, corner id ``4 * tag + k``; a frame without the grid
        one row with ``corner = -1`` and NaN pixels. ``attrs``: ``n_frames``, ``n_found``,
        ``order_methods`` (``aprilgrid``: the grid found, ``not_found``, ``undecodable``),
        ``n_cv_errors``, ``detector`` (:func:`cvsflow.board.aprilgrid_tags.passes_name`).

    Raises
    ------
    InputError
        A frame that is not a 2-D uint8 image, or no frames at all.
    """
    grid = aprilgrid_from_board(board)
    passes = default_passes() if passes is None else passes
    rows = CornerRows(grid.n_corners)
    methods: dict[str, int] = {}
    n_done = n_found = 0
    t_start = time.perf_counter()
    for frame, t_s, gray in frames:
        n_done += 1
        corners_px, method = None, "undecodable"
        if gray is not None:
            gray = np.asarray(gray)
            if gray.ndim != 2 or gray.dtype != np.uint8:
                raise InputError(f"video frame {frame}: expected an 8-bit grayscale image, got dtype "
                                 f"{gray.dtype}, shape {gray.shape}")
            ids, uv_px = detect_aprilgrid(gray, grid, passes)
            method = "aprilgrid" if len(ids) else "not_found"
            if len(ids):
                corners_px = np.full((grid.n_corners, 2), np.nan)
                corners_px[ids] = uv_px
        methods[method] = methods.get(method, 0) + 1
        n_found += corners_px is not None
        rows.add(frame, t_s, corners_px)
        if log_every and n_done % log_every == 0:
            log.info("corners (AprilGrid): %d%s frames done, grid found in %d", n_done,
                     f" of {n_frames}" if n_frames else "", n_found)
    if n_done == 0:
        raise InputError("video: no frames to extract corners from (expected at least one)")
    corners = rows.table()
    corners.attrs = {"n_frames": n_done, "n_found": n_found, "order_methods": methods,
                     "n_cv_errors": 0, "detector": passes_name(passes)}
    log.info("corners (AprilGrid, %s): grid found in %d of %d frames, %.1f frames/s",
             corners.attrs["detector"], n_found, n_done,
             n_done / max(time.perf_counter() - t_start, 1e-9))
    if n_done - n_found:
        log.warning("corners: %d frames without the AprilGrid kept as found=False", n_done - n_found)
    return corners
