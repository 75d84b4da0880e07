"""Corner refinement for calibration stills: a cornerSubPix window per corner, sized to its squares.

OpenCV's calibration sample refines every corner with one 11 px half window (23 x 23 px). Where
a board's squares are ~20 px, that window holds the neighbouring corners and the board's outer
edge, whose gradients are not orthogonal to the corner's offset, and cornerSubPix lands 2-5 px
off (OpenCV's ``left02.jpg``). Here each corner gets its own half window, with the video path's
square-scaled and blur-adapted refinement (:mod:`cvsflow.corners.refine`,
:mod:`cvsflow.corners.grid`) as its parts:

1. the *limit* ``w_max`` (:func:`window_limit_px`): the largest axis-aligned square window
   (plus the one-pixel border cornerSubPix differentiates over) that stays inside the four
   squares around the corner, i.e. inside the polygon through its 8 grid neighbours, with a
   margin for the edges' blur; for the corners of the outer rows the outside neighbours are the
   board's outline, measured in the image (:func:`outer_square_fracs`: OpenCV's sample board
   has cut outer squares, ~0.5 square deep on two sides) and placed by a local homography. No
   other corner and no other edge, the outline included, is ever in the window;
2. the *wanted* window: ``STILL_WINDOW_FRAC`` of the corner's local spacing
   (``local_spacing``), at least the window a blurred board needs (``BLUR_WINDOW_SIGMAS`` times
   the edges' blur sigma, ``edge_blur_px``), at least ``MIN_WINDOW_PX``;
3. ``w = min(wanted, w_max)``; cornerSubPix runs once per distinct ``w`` with the stills'
   criteria (``SUBPIX_CRITERIA``: 30 iterations or 0.001 px);
4. the video path's grid check (``grid_deviation`` against ``deviation_limit_px``): a corner
   off its neighbours' homography is refined once more from that prediction; if it still
   deviates it is *named* (``StillCorners.suspect``), not dropped.

``window_px`` (``cvsflow calibrate --subpix-window-px``) overrides all of this with one fixed
window, exactly OpenCV's sample's call (11 reproduces its published result).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.board import SUBPIX_CRITERIA, board_pattern
from cvsflow.corners import (
    BLUR_WINDOW_SIGMAS,
    MAX_GRID_DEVIATION_FRAC,
    deviation_limit_px,
    edge_blur_px,
    grid_deviation,
    local_spacing,
)

#: Smallest half window, px (cornerSubPix needs a few pixels of each edge).
MIN_WINDOW_PX = 2
#: Wanted half window as a share of the corner's local spacing. On 14 renders (fx 540, k1 -0.2,
#: 1602 corners) the median corner error against the truth was 0.042 / 0.033 / 0.028 / 0.025 px
#: at 0.15 / 0.25 (the video path's) / 0.35 / 0.5, the 11 px window's 0.027 px but with a
#: 9.9 px worst corner; on a wide lens (k1 -0.34) 0.35 and 0.5 tie (0.027 px). 0.35 keeps a
#: margin for stronger curvature over large squares.
STILL_WINDOW_FRAC = 0.35
#: Pixels kept between the window (with cornerSubPix's one-pixel gradient border) and the
#: nearest other edge: at least EDGE_MARGIN_PX, and EDGE_MARGIN_SIGMAS blur sigmas (a blurred
#: edge reaches that far towards the corner; at the bare limit the renders' corners with blur
#: sigma 1.5-2 px landed 0.8-1 px off).
EDGE_MARGIN_PX = 1.0
EDGE_MARGIN_SIGMAS = 2.5
#: The board's outline is taken this share of a square beyond the outer inner corners. A board
#: whose outer squares are whole has it at 1; OpenCV's sample board's outer squares are cut
#: (its outline is ~0.6 squares out), and with the outline assumed at 1 square the corners of
#: left02's near row took windows reaching it and moved 2-6 px.
OUTER_SQUARE_FRAC = 0.5
#: Smallest dark-to-light step (grey levels) of an outline profile (`outer_square_fracs`).
MIN_OUTLINE_CONTRAST = 30.0


@dataclass
class StillCorners:
    """A still's refined corners and how they were refined.

    Attributes
    ----------
    uv_px : ndarray, shape (nx * ny, 2)
        Refined corners in the order given, px.
    window_px : ndarray, shape (nx * ny,), int
        Half window used per corner, px.
    limit_px : ndarray, shape (nx * ny,)
        ``w_max`` of each corner (`window_limit_px`), px.
    blur_px : float
        Blur sigma of the board's edges, px (0 when not measured).
    suspect : dict
        Corner index -> reason, for corners that still deviate from their grid neighbours
        after a second refinement.
    """

    uv_px: np.ndarray
    window_px: np.ndarray
    limit_px: np.ndarray
    blur_px: float
    suspect: dict


def _beyond(p1, p2, p3, frac):
    """``frac`` of a step past p1 away from p2, the step scaled as the last two steps scale (a
    receding board's squares shrink geometrically); p3 may be None (two corners only)."""
    d = p1 - p2
    if p3 is None:
        return p1 + frac * d
    ratio = np.linalg.norm(d, axis=-1) / np.maximum(np.linalg.norm(p2 - p3, axis=-1), 1e-9)
    return p1 + np.asarray(frac)[..., None] * d * np.clip(ratio, 0.5, 2.0)[..., None]


def _sides(g):
    """The four sides of a (ny + 2, nx + 2, 2) ring grid as (outer corners, one row in, two rows
    in, setter of the ring row); top, bottom, left, right."""
    return {
        "top": (g[1, 1:-1], g[2, 1:-1], g[3, 1:-1] if len(g) > 4 else None, (0, slice(1, -1))),
        "bottom": (g[-2, 1:-1], g[-3, 1:-1], g[-4, 1:-1] if len(g) > 4 else None,
                   (-1, slice(1, -1))),
        "left": (g[1:-1, 1], g[1:-1, 2], g[1:-1, 3] if g.shape[1] > 4 else None,
                 (slice(1, -1), 0)),
        "right": (g[1:-1, -2], g[1:-1, -3], g[1:-1, -4] if g.shape[1] > 4 else None,
                  (slice(1, -1), -1)),
    }


def outer_square_fracs(gray: np.ndarray, corners_px: np.ndarray, board: dict) -> dict:
    """How far the board's outline lies beyond each side's outer corners, in squares.

    For each outer square of a side (between two neighbouring outer corners), the image is
    sampled from the middle of its inner edge outwards, 0 to 1.5 (extrapolated) squares, every
    half pixel. A dark outer square shows dark, then the sheet's light margin: the outline is
    where the profile first rises through the middle of its dark and light levels (steps of at
    least ``MIN_OUTLINE_CONTRAST`` grey levels only). Light outer squares show no outline. The
    median over a side's dark squares is its fraction.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order, px.
    board : dict

    Returns
    -------
    fracs : dict
        ``top``, ``bottom``, ``left``, ``right`` (rows of the grid order: ``top`` is the side
        of corner row 0) -> fraction of a square, or None where no outline was measured.
    """
    nx, ny = board_pattern(board)
    g = np.full((ny + 2, nx + 2, 2), np.nan)
    g[1:-1, 1:-1] = np.asarray(corners_px, np.float64).reshape(ny, nx, 2)
    out = {}
    s = np.arange(0.0, 1.5 + 1e-9, 0.02)  # in squares
    for name, (p1, p2, p3, _) in _sides(g).items():
        step = _beyond(p1, p2, p3, 1.0) - p1  # (n, 2): one square outwards at each corner
        a, b = p1[:-1], p1[1:]
        mid = 0.5 * (a + b)
        d = 0.5 * (step[:-1] + step[1:])
        pts = mid[:, None, :] + s[None, :, None] * d[:, None, :]
        prof = cv2.remap(gray, pts[..., 0].astype(np.float32), pts[..., 1].astype(np.float32),
                         cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=-1
                         ).astype(np.float64)
        inside = (pts[..., 0] >= 0) & (pts[..., 0] <= gray.shape[1] - 1) & (
            pts[..., 1] >= 0) & (pts[..., 1] <= gray.shape[0] - 1)
        fr = []
        for k in range(len(prof)):
            p, ok = prof[k], inside[k]
            near = p[(s >= 0.1) & (s <= 0.3) & ok]
            if len(near) < 3:
                continue
            dark = float(np.median(near))
            light = float(np.max(np.where(ok, p, -np.inf)))
            if light - dark < MIN_OUTLINE_CONTRAST:
                continue  # a light outer square (or a flat profile): no outline seen
            half = 0.5 * (dark + light)
            above = np.flatnonzero((s > 0.1) & ok & (p > half))
            if len(above):
                fr.append(float(s[above[0]]))
        out[name] = float(np.median(fr)) if fr else None
    return out


def _outline_point(grid_uv: np.ndarray, x: float, y: float) -> np.ndarray:
    """Image point of grid coordinate (x, y) outside the inner corners: the homography of the
    nearest 3 x 3 inner corners, extrapolated (perspective exact, lens curvature local)."""
    ny, nx = grid_uv.shape[:2]
    i0 = int(np.clip(round(x) - 1, 0, max(nx - 3, 0)))
    j0 = int(np.clip(round(y) - 1, 0, max(ny - 3, 0)))
    jj, ii = np.mgrid[j0:min(j0 + 3, ny), i0:min(i0 + 3, nx)]
    src = np.c_[ii.ravel(), jj.ravel()].astype(np.float64)
    dst = grid_uv[jj, ii].reshape(-1, 2)
    H, _ = cv2.findHomography(src, dst, 0)
    p = H @ np.array([x, y, 1.0])
    return p[:2] / p[2]


def _neighbour_polygons(uv: np.ndarray, nx: int, ny: int, fracs: dict | None = None
                        ) -> np.ndarray:
    """Each corner's 8 grid neighbours in order around it, (ny, nx, 8, 2), px. A neighbour off
    the inner grid is the board's outline there: per side the measured fraction of a square
    beyond the outer corners (``fracs``, `outer_square_fracs`; ``OUTER_SQUARE_FRAC`` where not
    measured), placed by `_outline_point`."""
    fracs = fracs or {}
    f = {k: (OUTER_SQUARE_FRAC if fracs.get(k) is None else float(fracs[k]))
         for k in ("top", "bottom", "left", "right")}
    g = np.asarray(uv, np.float64).reshape(ny, nx, 2)
    ring = [(-1, -1), (0, -1), (1, -1), (1, 0), (1, 1), (0, 1), (-1, 1), (-1, 0)]
    out = np.empty((ny, nx, 8, 2))
    cache = {}
    for j in range(ny):
        for i in range(nx):
            for k, (di, dj) in enumerate(ring):
                x, y = i + di, j + dj
                if 0 <= x < nx and 0 <= y < ny:
                    out[j, i, k] = g[y, x]
                    continue
                xo = -f["left"] if x < 0 else (nx - 1 + f["right"] if x >= nx else x)
                yo = -f["top"] if y < 0 else (ny - 1 + f["bottom"] if y >= ny else y)
                key = (xo, yo)
                if key not in cache:
                    cache[key] = _outline_point(g, xo, yo)
                out[j, i, k] = cache[key]
    return out


def window_limit_px(corners_px: np.ndarray, board: dict, blur_px: float = 0.0,
                    outline_fracs: dict | None = None) -> np.ndarray:
    """Largest half window per corner that keeps cornerSubPix inside the corner's four squares.

    Parameters
    ----------
    corners_px : ndarray, shape (nx * ny, 2)
        Corners in grid order (row-major, rows of nx), px.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    blur_px : float
        Blur sigma of the edges, px (widens the margin).
    outline_fracs : dict, optional
        `outer_square_fracs` of the still (default: ``OUTER_SQUARE_FRAC`` on every side).

    Returns
    -------
    w_max_px : ndarray, shape (nx * ny,)
        For corner q and the polygon P through its 8 grid neighbours (in order around it; a
        corner of the outer rows uses the outline, ``OUTER_SQUARE_FRAC`` of a square out), the
        largest w with the
        axis-aligned square of half side ``w + 1 + margin`` (the window, cornerSubPix's
        gradient border, ``margin = max(EDGE_MARGIN_PX, EDGE_MARGIN_SIGMAS * blur_px)``) inside
        P: ``min over P's edges of dist(q, edge line) / (|n_u| + |n_v|) - 1 - margin``, n the
        edge's unit normal. Not rounded.
    """
    nx, ny = board_pattern(board)
    uv = np.asarray(corners_px, np.float64).reshape(-1, 2)
    q = uv.reshape(ny, nx, 2)
    poly = _neighbour_polygons(uv, nx, ny, outline_fracs)  # (ny, nx, 8, 2)
    a = poly
    b = np.roll(poly, -1, axis=2)
    e = b - a
    length = np.linalg.norm(e, axis=-1)
    n = np.stack([-e[..., 1], e[..., 0]], axis=-1) / np.maximum(length, 1e-12)[..., None]
    dist = np.abs(np.sum((q[:, :, None, :] - a) * n, axis=-1))
    support = np.abs(n[..., 0]) + np.abs(n[..., 1])
    margin = max(EDGE_MARGIN_PX, EDGE_MARGIN_SIGMAS * float(blur_px))
    w = np.min(dist / support, axis=2) - 1.0 - margin
    return w.reshape(-1)


def _subpix(gray, pts, w):
    """cornerSubPix of points (n, 2) with half window w and the stills' criteria; (n, 2)."""
    p = np.asarray(pts, np.float32).reshape(-1, 1, 2).copy()
    h, wd = gray.shape[:2]
    p[..., 0] = np.clip(p[..., 0], 0, wd - 1.001)
    p[..., 1] = np.clip(p[..., 1], 0, h - 1.001)
    return cv2.cornerSubPix(gray, p, (int(w), int(w)), (-1, -1), SUBPIX_CRITERIA).reshape(-1, 2)


def refine_still_corners(gray: np.ndarray, corners_px: np.ndarray, board: dict,
                         window_px: int | None = None, frac: float = STILL_WINDOW_FRAC,
                         adapt_to_blur: bool = True) -> StillCorners:
    """Refine a still's detected corners, each with a window sized to its squares.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    corners_px : ndarray, shape (nx * ny, 2) or (nx * ny, 1, 2)
        Detected corners (``findChessboardCorners``) in grid order (OpenCV's or board order:
        rows of nx), px.
    board : dict
        ``squares_x``, ``squares_y``, ``square_m``.
    window_px : int, optional
        Fixed half window for every corner (``--subpix-window-px``): exactly
        ``cv2.cornerSubPix(gray, corners, (w, w), (-1, -1), SUBPIX_CRITERIA)``, no grid check.
    frac : float
        Wanted half window as a share of the corner's local spacing.
    adapt_to_blur : bool
        Widen the window to ``BLUR_WINDOW_SIGMAS`` blur sigmas where the limit allows.

    Returns
    -------
    StillCorners
    """
    uv0 = np.asarray(corners_px, np.float64).reshape(-1, 2)
    if window_px is not None:
        w = int(window_px)
        uv = _subpix(gray, uv0, w).astype(np.float64)
        return StillCorners(uv, np.full(len(uv), w), window_limit_px(uv0, board), 0.0, {})
    spacing = local_spacing(uv0, board)
    wanted = np.maximum(MIN_WINDOW_PX, np.rint(frac * spacing))
    blur = float(edge_blur_px(gray, uv0, board))
    fracs = outer_square_fracs(gray, uv0, board)
    limit = window_limit_px(uv0, board, blur, fracs)
    if adapt_to_blur:
        wanted = np.maximum(wanted, np.ceil(BLUR_WINDOW_SIGMAS * blur))
    w = np.maximum(MIN_WINDOW_PX, np.minimum(wanted, np.floor(limit))).astype(int)
    uv = np.empty_like(uv0)
    for wk in np.unique(w):
        sel = w == wk
        uv[sel] = _subpix(gray, uv0[sel], wk)
    # The video path's grid check: off the neighbours' homography -> once more from there.
    suspect = {}
    lim_dev = deviation_limit_px(uv, board, MAX_GRID_DEVIATION_FRAC)
    predicted, dev = grid_deviation(uv, board)
    bad = np.isfinite(dev) & (dev > lim_dev)
    if bad.any():
        for k in np.flatnonzero(bad):
            uv[k] = _subpix(gray, predicted[k:k + 1], w[k])[0]
        _, dev2 = grid_deviation(uv, board)
        for k in np.flatnonzero(bad & np.isfinite(dev2) & (dev2 > lim_dev)):
            suspect[int(k)] = (f"{dev2[k]:.2f} px off its grid neighbours' homography "
                               f"(limit {lim_dev[k]:.2f} px) after a second refinement")
    return StillCorners(uv, w, limit, blur, suspect)
