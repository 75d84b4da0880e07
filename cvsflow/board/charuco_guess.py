"""Which ChArUco board a set of stills shows: its dictionary, squares and marker size.

``cvsflow init`` reads a recording folder before the user has said what board they printed. A
chessboard is found by trying common sizes; a ChArUco board says more about itself: its
markers name their dictionary, and where each marker id sits in the image fixes the number of
squares per row (marker i is the i-th white square in row-major order, so a wrong row length
puts the ids in the wrong places). The number of rows is only bounded below by the highest id
seen, and the square's size in metres is never in an image.
"""

from __future__ import annotations

import cv2
import numpy as np

# One dictionary per family (a smaller one is the first ids of its family's largest), the
# largest first tried; ``DICT_ARUCO_ORIGINAL`` is its own family.
FAMILIES = {
    "DICT_4X4": (50, 100, 250, 1000),
    "DICT_5X5": (50, 100, 250, 1000),
    "DICT_6X6": (50, 100, 250, 1000),
    "DICT_7X7": (50, 100, 250, 1000),
    "DICT_ARUCO_ORIGINAL": (),
}
MIN_MARKERS = 6  # per still, for the layout fit to mean anything
MAX_SQUARES = 24  # longest row tried
# A row length is taken when its layout fits the markers' centres to this share of a marker's
# side and the next best fits at least twice as badly.
MAX_FIT_SHARE = 0.1


def _detect(gray, family):
    name = family if family == "DICT_ARUCO_ORIGINAL" else f"{family}_{FAMILIES[family][-1]}"
    detector = cv2.aruco.ArucoDetector(cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, name)))
    corners, ids, _ = detector.detectMarkers(gray)
    if ids is None:
        return np.empty((0, 4, 2)), np.empty(0, int)
    return np.asarray(corners, float).reshape(-1, 4, 2), ids.ravel().astype(int)


def _white_square_centres(squares_x: int, n_markers: int) -> np.ndarray:
    """Centre of marker i's square, in squares, for a board ``squares_x`` wide (OpenCV >= 4.6
    pattern: square (0, 0) black, so the white squares of row r start at column (r + 1) % 2)."""
    out = []
    r = 0
    while len(out) < n_markers:
        out += [(c + 0.5, r + 0.5) for c in range((r + 1) % 2, squares_x, 2)]
        r += 1
    return np.asarray(out[:n_markers], float)


def _layout_misfit(squares_x, views) -> float:
    """RMS distance (in marker sides) of the seen markers' centres from where a board
    ``squares_x`` wide puts them, through each view's best homography."""
    n = max(int(ids.max()) for _, ids in views) + 1
    centres_B = _white_square_centres(squares_x, n)
    err2, count = 0.0, 0
    for corners, ids in views:
        uv = corners.mean(axis=1)
        side = np.median(np.linalg.norm(np.diff(corners, axis=1, append=corners[:, :1]), axis=-1))
        H, _ = cv2.findHomography(centres_B[ids].astype(np.float32), uv.astype(np.float32), 0)
        if H is None:
            return np.inf
        pred = cv2.perspectiveTransform(centres_B[ids].reshape(-1, 1, 2), H).reshape(-1, 2)
        err2 += float(np.sum((pred - uv) ** 2)) / side**2
        count += len(ids)
    return float(np.sqrt(err2 / count))


def guess_charuco_board(images) -> dict | None:
    """The ChArUco board that grey stills show, as far as images can tell.

    Parameters
    ----------
    images : iterable of ndarray
        8-bit grey stills of the board (a few suffice; each needs ``MIN_MARKERS`` markers).

    Returns
    -------
    guess : dict or None
        None when no still shows enough markers of one dictionary. Else ``dictionary`` (the
        smallest of its family that holds every id seen), ``n_markers_seen``, ``max_id``,
        ``squares_x`` (None when no row length fits: a legacy-pattern or other board),
        ``squares_y_min`` (the fewest rows that hold ``max_id``: the board may have more),
        ``marker_share`` (the marker's side over the square's, from the views' homographies)
        and ``fit_share`` (the layout's RMS misfit in marker sides).
    """
    images = [np.asarray(g) for g in images]
    best = None
    for family in FAMILIES:
        views = [v for v in (_detect(g, family) for g in images) if len(v[1]) >= MIN_MARKERS]
        n_seen = sum(len(ids) for _, ids in views)
        if views and (best is None or n_seen > best[2]):
            best = (family, views, n_seen)
    if best is None:
        return None
    family, views, n_seen = best
    max_id = max(int(ids.max()) for _, ids in views)
    sizes = FAMILIES[family]
    dictionary = family if not sizes else f"{family}_{next(s for s in sizes if s > max_id)}"
    fits = sorted((_layout_misfit(sx, views), sx) for sx in range(3, MAX_SQUARES + 1))
    squares_x = None
    if fits and fits[0][0] < MAX_FIT_SHARE and (len(fits) == 1 or fits[1][0] > 2 * fits[0][0]):
        squares_x = int(fits[0][1])
    out = {"dictionary": dictionary, "n_markers_seen": int(n_seen), "max_id": max_id,
           "squares_x": squares_x, "squares_y_min": None, "marker_share": None,
           "fit_share": float(fits[0][0]) if fits else float("inf")}
    if squares_x is None:
        return out
    sy = 2
    while (squares_x * sy) // 2 < max_id + 1:
        sy += 1
    out["squares_y_min"] = sy
    centres_B = _white_square_centres(squares_x, max_id + 1)
    shares = []
    for corners, ids in views:
        H, _ = cv2.findHomography(corners.mean(axis=1).astype(np.float32),
                                  centres_B[ids].astype(np.float32), 0)
        c_B = cv2.perspectiveTransform(corners.reshape(-1, 1, 2), H).reshape(-1, 4, 2)
        shares.append(np.linalg.norm(np.diff(c_B, axis=1, append=c_B[:, :1]), axis=-1).ravel())
    out["marker_share"] = float(np.median(np.concatenate(shares)))
    return out
