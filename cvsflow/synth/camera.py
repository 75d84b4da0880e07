"""Camera model, board texture and image rendering of the demo session.

The board is rendered in one resampling step per instant: for every pixel of the distorted
image, its undistorted normalised ray (computed once per camera) is mapped by the plane
homography into the board texture, and ``cv2.remap`` samples the texture there. A pyramid of
area-averaged textures keeps far boards free of aliasing. Motion blur is the mean of several
such renders over the exposure time.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.charuco import charuco_board
from cvsflow.transforms import invert_T

A1_SHEET_M = (0.841, 0.594)  # printed sheet, width x height, metres
INK_REFLECTANCE = 0.06
MARKER_RADIUS_M = 0.007  # 14 mm Vicon marker
PAPER_REFLECTANCE = 0.88
# Beyond this normalised radius the 5-term polynomial is no longer a physical lens
# (it folds back); rays there are far outside a 640x480 image at f ~ 700 px (r ~ 0.6).
MAX_RAY_RADIUS = 1.2


@dataclass(frozen=True)
class Board:
    """Chessboard geometry in the board frame B (origin at inner corner 0, z into the board).

    Attributes are metres; ``nx``, ``ny`` count inner corners along x and y. ``kind``
    ``"charuco"`` adds ArUco markers of side ``marker_m`` from ``dictionary`` to the white
    squares (``cvsflow.charuco``); the squares and corners are the chessboard's.
    """

    squares_x: int
    squares_y: int
    square_m: float
    kind: str = "chessboard"
    marker_m: float = 0.0
    dictionary: str = ""

    def config(self) -> dict:
        """The board's config block (``board:``): the chessboard's three keys, plus
        ``type``, ``marker_m`` and ``dictionary`` for a ChArUco board."""
        out = {"squares_x": self.squares_x, "squares_y": self.squares_y,
               "square_m": self.square_m}
        if self.kind == "charuco":
            out.update(type="charuco", marker_m=self.marker_m, dictionary=self.dictionary)
        return out

    @property
    def nx(self) -> int:
        return self.squares_x - 1

    @property
    def ny(self) -> int:
        return self.squares_y - 1

    def corners_B(self) -> np.ndarray:
        """Inner corners, shape (nx * ny, 3): corner k at ((k % nx) s, (k // nx) s, 0)."""
        k = np.arange(self.nx * self.ny)
        return np.stack(
            [(k % self.nx) * self.square_m, (k // self.nx) * self.square_m, 0.0 * k], axis=1
        )

    def printed_B(self):
        """Printed squares' extent in B: (x_min, x_max, y_min, y_max), metres."""
        s = self.square_m
        return (-s, (self.squares_x - 1) * s, -s, (self.squares_y - 1) * s)

    def sheet_B(self):
        """A1 sheet's extent in B, centred on the printed squares: (x0, x1, y0, y1), metres."""
        x0, x1, y0, y1 = self.printed_B()
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        w, h = A1_SHEET_M
        return (cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2)

    def center_B(self) -> np.ndarray:
        """Centre of the inner-corner grid, shape (3,), metres."""
        return np.array([(self.nx - 1) * self.square_m / 2, (self.ny - 1) * self.square_m / 2, 0])



def rectangle_outline_B(extent, n_per_edge=8) -> np.ndarray:
    """Points along the board-plane rectangle ``extent`` = (x0, x1, y0, y1), shape (4 n, 3).

    Parameters
    ----------
    extent : (float, float, float, float)
        ``(x0, x1, y0, y1)`` of the rectangle in the board frame B, metres.
    n_per_edge : int
        Points per edge, evenly spaced, each edge's start included and its end left out.

    Returns
    -------
    points_B : ndarray, shape (4 * n_per_edge, 3)
        The outline in B (z = 0), metres, walked from (x0, y0) towards (x1, y0) and round.
    """
    x0, x1, y0, y1 = extent
    u = np.linspace(0.0, 1.0, n_per_edge, endpoint=False)
    edges = [
        np.stack([x0 + (x1 - x0) * u, np.full_like(u, y0)], 1),
        np.stack([np.full_like(u, x1), y0 + (y1 - y0) * u], 1),
        np.stack([x1 - (x1 - x0) * u, np.full_like(u, y1)], 1),
        np.stack([np.full_like(u, x0), y1 - (y1 - y0) * u], 1),
    ]
    xy = np.concatenate(edges)
    return np.column_stack([xy, np.zeros(len(xy))])


def camera_from_config(camera_cfg):
    """Camera matrix K (3, 3) px and distortion (5,) [k1, k2, p1, p2, k3] from the synth config.

    Parameters
    ----------
    camera_cfg : dict
        ``synth.camera``: ``fx_px``, ``fy_px``, ``cx_px``, ``cy_px`` (px) and ``dist``
        (OpenCV order; its length is not checked here).

    Returns
    -------
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray
        Distortion coefficients as given, float.
    """
    K = np.array(
        [
            [camera_cfg["fx_px"], 0.0, camera_cfg["cx_px"]],
            [0.0, camera_cfg["fy_px"], camera_cfg["cy_px"]],
            [0.0, 0.0, 1.0],
        ]
    )
    return K, np.asarray(camera_cfg["dist"], dtype=float)


def distort_normalised(xy, dist):
    """OpenCV's 5-term lens model on normalised rays ``xy`` (..., 2); returns (..., 2).

    Parameters
    ----------
    xy : ndarray, shape (..., 2)
        Undistorted normalised image coordinates (x / z, y / z in the camera frame C).
    dist : array_like, shape (5,)
        ``[k1, k2, p1, p2, k3]``.

    Returns
    -------
    xy_d : ndarray, shape (..., 2)
        Distorted normalised coordinates (pixels are ``K @ [xd, yd, 1]``).
    """
    k1, k2, p1, p2, k3 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def project_points(T_C_B, p_B, K, dist):
    """Distorted pixel positions of board points, as ``cv2.projectPoints`` would give.

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4) or (N, 4, 4)
        Board in camera, metres.
    p_B : ndarray, shape (M, 3)
        Points in B, metres.
    K, dist : ndarray
        Camera matrix (3, 3) px, distortion (5,).

    Returns
    -------
    uv_px : ndarray, shape (M, 2) or (N, M, 2)
        Pixels; NaN for points behind the camera or on rays outside the lens model's
        valid domain (normalised radius > ``MAX_RAY_RADIUS``), where the polynomial folds back.
    """
    T_C_B = np.asarray(T_C_B, dtype=float)
    p_C = np.einsum("...ij,mj->...mi", T_C_B[..., :3, :3], p_B) + T_C_B[..., None, :3, 3]
    z = p_C[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = p_C[..., :2] / z
    valid = (z[..., 0] > 1e-6) & (np.sum(xy * xy, axis=-1) < MAX_RAY_RADIUS**2)
    xy_d = distort_normalised(np.where(valid[..., None], xy, 0.0), dist)
    uv = np.stack([K[0, 0] * xy_d[..., 0] + K[0, 2], K[1, 1] * xy_d[..., 1] + K[1, 2]], -1)
    return np.where(valid[..., None], uv, np.nan)


def undistortion_grid(K, dist, size):
    """Undistorted normalised ray of every pixel of the distorted image.

    Parameters
    ----------
    K, dist : ndarray
        Camera matrix (3, 3) px, distortion (5,).
    size : tuple of int
        Image (width, height), px.

    Returns
    -------
    xy_n : ndarray, shape (height, width, 2), float64
        Normalised ray (x/z, y/z) whose distorted projection is the pixel centre.
    """
    width, height = size
    u, v = np.meshgrid(np.arange(width, dtype=float), np.arange(height, dtype=float))
    uv = np.stack([u, v], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    xy = cv2.undistortPointsIter(uv, K, dist, None, None, criteria).reshape(height, width, 2)
    # Polish with Newton steps on the forward model: the forward model defines the truth.
    target = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1]], axis=-1)
    eps = 1e-7
    for _ in range(3):
        f = distort_normalised(xy, dist) - target
        jx = (distort_normalised(xy + [eps, 0.0], dist) - distort_normalised(xy, dist)) / eps
        jy = (distort_normalised(xy + [0.0, eps], dist) - distort_normalised(xy, dist)) / eps
        det = jx[..., 0] * jy[..., 1] - jy[..., 0] * jx[..., 1]
        dx = (jy[..., 1] * f[..., 0] - jy[..., 0] * f[..., 1]) / det
        dy = (-jx[..., 1] * f[..., 0] + jx[..., 0] * f[..., 1]) / det
        xy = xy - np.stack([dx, dy], axis=-1)
    return xy


@dataclass(frozen=True)
class BoardTexture:
    """Board texture pyramid: level l has ``ppm[l]`` texels per metre.

    ``levels[l]`` has shape (rows, cols, 2), float32: channel 0 reflectance times coverage
    (premultiplied), channel 1 coverage of the sheet (alpha). Texel (c, r) has its centre at
    B = (x0 + (c + 0.5) / ppm, y0 + (r + 0.5) / ppm).
    """

    levels: tuple
    ppm: tuple
    x0_m: float
    y0_m: float


def make_board_texture(board: Board, ppm=1200.0, n_levels=5, markers_B=None) -> BoardTexture:
    """Render the A1 sheet with its chessboard as a texture pyramid.

    The square diagonally outside inner corner 0 (negative x and y) is black, so the corner
    order is unambiguous (6x5 squares: a 180 degree turn makes that square white).

    Parameters
    ----------
    board : Board
    ppm : float
        Texels per metre of the finest level.
    n_levels : int
        Pyramid levels, each half the resolution of the previous one.
    markers_B : ndarray, shape (M, 3), optional
        Vicon markers stuck on the sheet (frame B, metres); those over the sheet are drawn
        as grey discs of ``MARKER_RADIUS_M`` seen face-on (their relief is ignored).

    Returns
    -------
    BoardTexture
        ``n_levels`` levels, the finest at ``ppm`` texels per metre, with texel edges on the
        square edges and one empty texel ring round the sheet.
    """
    s = board.square_m
    x_min, _, y_min, _ = board.printed_B()
    sx0, sx1, sy0, sy1 = board.sheet_B()
    # Put texel boundaries on the square edges (x_min + k s), one empty texel ring outside.
    step = 2**n_levels
    x0 = x_min - np.ceil((x_min - sx0) * ppm + 1) / ppm
    y0 = y_min - np.ceil((y_min - sy0) * ppm + 1) / ppm
    cols = int(np.ceil(((sx1 - x0) * ppm + 2) / step) * step)
    rows = int(np.ceil(((sy1 - y0) * ppm + 2) / step) * step)
    # Area coverage of the sheet by each texel, exact for axis-aligned edges.
    edges_x = x0 + np.arange(cols + 1) / ppm
    edges_y = y0 + np.arange(rows + 1) / ppm
    cover_x = np.clip(np.minimum(edges_x[1:], sx1) - np.maximum(edges_x[:-1], sx0), 0, None) * ppm
    cover_y = np.clip(np.minimum(edges_y[1:], sy1) - np.maximum(edges_y[:-1], sy0), 0, None) * ppm
    alpha = np.outer(cover_y, cover_x)
    xc = x0 + (np.arange(cols) + 0.5) / ppm
    yc = y0 + (np.arange(rows) + 0.5) / ppm
    ix = np.floor((xc - x_min) / s).astype(int)
    iy = np.floor((yc - y_min) / s).astype(int)
    in_x = (ix >= 0) & (ix < board.squares_x)
    in_y = (iy >= 0) & (iy < board.squares_y)
    black = ((iy[:, None] + ix[None, :]) % 2 == 0) & in_y[:, None] & in_x[None, :]
    if board.kind == "charuco":
        black |= _charuco_marker_ink(board, xc - x_min, yc - y_min)
    reflectance = np.where(black, INK_REFLECTANCE, PAPER_REFLECTANCE)
    if markers_B is not None:
        reflectance = _draw_markers(reflectance, markers_B, x0, y0, ppm, board.sheet_B())
    level = np.dstack([reflectance * alpha, alpha]).astype(np.float32)
    return texture_pyramid(level, ppm, n_levels, x0, y0)


# Pixels per marker bit of the ChArUco image the markers are copied from (many more than
# texels per bit: the copy's edges are off by at most half a texel).
CHARUCO_PX_PER_BIT = 24


def _charuco_marker_ink(board: Board, x_m, y_m):
    """(len(y_m), len(x_m)) bool: texel centres (x_m, y_m: metres from the printed squares'
    outer corner, along B's x and y) on a marker's black bit.

    The markers come from ``cv2.aruco.CharucoBoard.generateImage`` (image row = B's y, square
    (0, 0) black, markers in the white squares); only marker pixels inside white squares are
    taken, so the squares, and with them every corner, stay exactly the chessboard's.
    """
    cb = charuco_board(board.config())
    bits = cb.getDictionary().markerSize + 2  # the marker and its one-bit black border
    pps = int(np.ceil(CHARUCO_PX_PER_BIT * bits * board.square_m / board.marker_m))
    image = cb.generateImage((board.squares_x * pps, board.squares_y * pps), marginSize=0,
                             borderBits=1)
    s = board.square_m
    ci = np.floor(np.asarray(x_m) / s * pps).astype(int)
    ri = np.floor(np.asarray(y_m) / s * pps).astype(int)
    in_c = (ci >= 0) & (ci < image.shape[1])
    in_r = (ri >= 0) & (ri < image.shape[0])
    ink = image[np.clip(ri, 0, image.shape[0] - 1)][:, np.clip(ci, 0, image.shape[1] - 1)] < 128
    white_square = ((ri[:, None] // pps + ci[None, :] // pps) % 2) == 1
    return ink & white_square & in_r[:, None] & in_c[None, :]


def texture_pyramid(level, ppm, n_levels, x0, y0) -> BoardTexture:
    """A BoardTexture of ``n_levels`` halvings (area-averaged) of a (rows, cols, 2) level.

    Parameters
    ----------
    level : ndarray, shape (rows, cols, 2), float32
        Finest level: premultiplied reflectance and coverage (see :class:`BoardTexture`).
        ``rows`` and ``cols`` should divide by ``2 ** (n_levels - 1)``.
    ppm : float
        Texels per metre of ``level``.
    n_levels : int
        Levels in all, ``level`` included.
    x0, y0 : float
        Board-frame B position of the texture's top-left texel corner, metres.

    Returns
    -------
    BoardTexture
        Level l at ``ppm / 2**l`` texels per metre.
    """
    levels, ppms = [level], [ppm]
    for _ in range(n_levels - 1):
        level = cv2.resize(level, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        levels.append(level)
        ppms.append(ppms[-1] / 2)
    return BoardTexture(tuple(levels), tuple(ppms), float(x0), float(y0))


def _draw_markers(reflectance, markers_B, x0, y0, ppm, sheet):
    """Paint retro-reflective markers (grey, darker rim) on the sheet texture."""
    reflectance = reflectance.astype(np.float32).copy()
    shift = 4  # cv2.circle sub-texel precision, 1/16 texel
    sx0, sx1, sy0, sy1 = sheet
    for x, y, _ in np.asarray(markers_B, dtype=float):
        if not (sx0 < x < sx1 and sy0 < y < sy1):
            continue  # a marker off the sheet (on a stick or a tab) is not in the texture
        centre = (int(round(((x - x0) * ppm - 0.5) * 16)), int(round(((y - y0) * ppm - 0.5) * 16)))
        radius = MARKER_RADIUS_M * ppm
        cv2.circle(reflectance, centre, int(radius * 16), 0.35, -1, cv2.LINE_AA, shift)
        cv2.circle(reflectance, centre, int(0.75 * radius * 16), 0.6, -1, cv2.LINE_AA, shift)
    return reflectance


def _texel_from_ray(T_C_B, texture: BoardTexture, level: int):
    """Homography (3, 3) from a normalised ray (x, y, 1) in C to texel coordinates of a level."""
    T_B_C = invert_T(T_C_B)
    # Plane z_B = 0 seen from C: ray d (in C) hits it at B point o + lambda R d, with
    # lambda = -o_z / (R d)_z; the homography is that map up to scale.
    R, o = T_B_C[:3, :3], T_B_C[:3, 3]
    H_B = np.zeros((3, 3))
    H_B[0] = o[0] * R[2] - o[2] * R[0]
    H_B[1] = o[1] * R[2] - o[2] * R[1]
    H_B[2] = R[2]
    ppm = texture.ppm[level]
    A = np.array(
        [
            [ppm, 0.0, -texture.x0_m * ppm - 0.5],
            [0.0, ppm, -texture.y0_m * ppm - 0.5],
            [0.0, 0.0, 1.0],
        ]
    )
    return A @ H_B


def choose_level(T_C_B, K, texture: BoardTexture) -> int:
    """Finest pyramid level with at most ~1.4 texels per pixel at the board centre.

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4)
        Board in camera, metres; its origin's depth (held at >= 1 mm) sets the scale.
    K : ndarray, shape (3, 3)
        Camera matrix, px (``fx`` is used).
    texture : BoardTexture

    Returns
    -------
    int
        Level index, 0 (finest) to ``len(texture.levels) - 1``.
    """
    depth_m = max(float(T_C_B[2, 3]), 1e-3)
    px_per_m = K[0, 0] / depth_m
    level = 0
    while level + 1 < len(texture.levels) and texture.ppm[level] > 1.4 * px_per_m:
        level += 1
    return level


def render_board(T_C_B, texture: BoardTexture, xy_n, K, dist, roi=None):
    """Premultiplied board reflectance and sheet coverage at one instant.

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4)
        Board in camera, metres.
    texture : BoardTexture
    xy_n : ndarray, shape (H, W, 2)
        ``undistortion_grid`` of the camera.
    K, dist : ndarray
        Camera matrix and distortion (only used to choose the level and the region).
    roi : tuple of int, optional
        (x0, y0, x1, y1) pixel region to render; by default the board's bounding box.

    Returns
    -------
    layer : ndarray, shape (H, W, 2), float32
        Channel 0 reflectance times coverage, channel 1 coverage (0..1).
    """
    height, width = xy_n.shape[:2]
    layer = np.zeros((height, width, 2), np.float32)
    if roi is None:
        roi = board_roi(T_C_B, texture, K, dist, (width, height))
    if roi is None:
        return layer
    x0, y0, x1, y1 = roi
    layer[y0:y1, x0:x1] = render_board_region(T_C_B, texture, xy_n, K, roi)
    return layer


def render_board_region(T_C_B, texture: BoardTexture, xy_n, K, roi):
    """``render_board`` inside the pixel box ``roi`` = (x0, y0, x1, y1) only: shape (y1-y0, x1-x0, 2).

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4)
        Board in camera, metres.
    texture : BoardTexture
    xy_n : ndarray, shape (H, W, 2)
        ``undistortion_grid`` of the camera.
    K : ndarray, shape (3, 3)
        Camera matrix, px (only used to choose the level).
    roi : (int, int, int, int)
        ``(x0, y0, x1, y1)``, pixels, end-exclusive, inside the image.

    Returns
    -------
    layer : ndarray, shape (y1 - y0, x1 - x0, 2), float32
        Channel 0 reflectance times coverage, channel 1 coverage (0..1); 0 where the pixel's
        ray misses the sheet or meets the board plane behind the camera.
    """
    x0, y0, x1, y1 = roi
    level = choose_level(T_C_B, K, texture)
    G = _texel_from_ray(T_C_B, texture, level)
    rays = xy_n[y0:y1, x0:x1]
    den = G[2, 0] * rays[..., 0] + G[2, 1] * rays[..., 1] + G[2, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        map_c = (G[0, 0] * rays[..., 0] + G[0, 1] * rays[..., 1] + G[0, 2]) / den
        map_r = (G[1, 0] * rays[..., 0] + G[1, 1] * rays[..., 1] + G[1, 2]) / den
    # Rays that meet the board plane behind the camera must sample nothing.
    hits = _rays_hit_front(T_C_B, rays) > 0
    map_c = np.where(hits, map_c, -10.0).astype(np.float32)
    map_r = np.where(hits, map_r, -10.0).astype(np.float32)
    return cv2.remap(
        texture.levels[level],
        map_c,
        map_r,
        interpolation=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
        borderValue=0,
    )


def _rays_hit_front(T_C_B, rays):
    """Positive where the ray (x, y, 1) meets the board plane in front of the camera."""
    n_C = T_C_B[:3, 2]  # board z axis in C
    d = float(n_C @ T_C_B[:3, 3])  # plane: n . p = d
    dot = n_C[0] * rays[..., 0] + n_C[1] * rays[..., 1] + n_C[2]
    return dot * d


def board_roi(T_C_B, texture: BoardTexture, K, dist, size, pad_px=3):
    """Pixel box (x0, y0, x1, y1) holding the sheet, the whole image if unsure, None if unseen.

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4)
        Board in camera, metres.
    texture : BoardTexture
        Its extent in B (the whole texture, empty ring included) is what is boxed.
    K : ndarray, shape (3, 3)
        Camera matrix, px.
    dist : ndarray, shape (5,)
        Distortion [k1, k2, p1, p2, k3].
    size : (int, int)
        Image (width, height), px.
    pad_px : int
        Margin added round the projected outline, px.

    Returns
    -------
    roi : (int, int, int, int) or None
        ``(x0, y0, x1, y1)`` clipped to the image, end-exclusive, px. The whole image when an
        outline point cannot be projected (NaN: behind the camera or off the lens model's
        domain); None when the box lies outside the image.
    """
    width, height = size
    x_a = texture.x0_m
    y_a = texture.y0_m
    rows, cols = texture.levels[0].shape[:2]
    extent = (x_a, x_a + cols / texture.ppm[0], y_a, y_a + rows / texture.ppm[0])
    outline = rectangle_outline_B(extent, n_per_edge=16)
    uv = project_points(T_C_B, outline, K, dist)
    if not np.all(np.isfinite(uv)):
        # part of the sheet is off the lens model's domain: render the whole frame
        return (0, 0, width, height)
    x0 = int(max(np.floor(uv[:, 0].min()) - pad_px, 0))
    y0 = int(max(np.floor(uv[:, 1].min()) - pad_px, 0))
    x1 = int(min(np.ceil(uv[:, 0].max()) + pad_px + 1, width))
    y1 = int(min(np.ceil(uv[:, 1].max()) + pad_px + 1, height))
    if x1 <= x0 or y1 <= y0:
        return None
    return (x0, y0, x1, y1)


def make_background(rng, size, n_rects=60, light=False):
    """Static cluttered background reflectance, shape (height, width), float32 in 0..1.

    Random rectangles (furniture, posters) over a smooth texture; ``light`` gives the pale,
    plain background of the calibration stills.

    Parameters
    ----------
    rng : numpy.random.Generator
        Draws the texture, the rectangles and the fine noise.
    size : (int, int)
        Image (width, height), px.
    n_rects : int
        Random rectangles drawn.
    light : bool
        Map the result to 0.75..0.95 (the stills' pale background).

    Returns
    -------
    background : ndarray, shape (height, width), float32
        Reflectance in 0..1.
    """
    width, height = size
    coarse = rng.uniform(0.0, 1.0, size=(height // 16 + 2, width // 16 + 2)).astype(np.float32)
    img = cv2.resize(coarse, (width, height), interpolation=cv2.INTER_CUBIC)
    img = 0.25 + 0.3 * img
    for _ in range(n_rects):
        w, h = rng.integers(8, width // 3), rng.integers(8, height // 3)
        x, y = rng.integers(-w // 2, width), rng.integers(-h // 2, height)
        img[max(y, 0) : y + h, max(x, 0) : x + w] = rng.uniform(0.05, 0.95)
    fine = rng.normal(0.0, 0.04, size=(height, width)).astype(np.float32)
    img = cv2.GaussianBlur(img, (0, 0), 1.2) + cv2.GaussianBlur(fine, (0, 0), 0.8)
    if light:
        img = 0.75 + 0.2 * img
    return np.clip(img, 0.0, 1.0).astype(np.float32)


def vignetting(size, K, strength=0.25):
    """Smooth multiplicative shading, shape (height, width), 1 at the principal point.

    Parameters
    ----------
    size : (int, int)
        Image (width, height), px.
    K : ndarray, shape (3, 3)
        Camera matrix, px: the shading is ``1 - strength * r^2`` with r the normalised
        distance ``((u - cx) / fx, (v - cy) / fy)`` from the principal point.
    strength : float
        Fall-off per unit squared normalised radius.

    Returns
    -------
    shading : ndarray, shape (height, width), float32
        Multiplier of the scene radiance, dimensionless.
    """
    width, height = size
    u, v = np.meshgrid(np.arange(width, dtype=np.float32), np.arange(height, dtype=np.float32))
    r2 = ((u - K[0, 2]) / K[0, 0]) ** 2 + ((v - K[1, 2]) / K[1, 1]) ** 2
    return (1.0 - strength * r2).astype(np.float32)


def expose(radiance, gain, offset, defocus_sigma_px, noise_sigma, rng, shot_gain=0.02, analog_gain=1.0):
    """Sensor model: grey = gain * radiance + offset, defocus blur, noise; uint8.

    Parameters
    ----------
    radiance : ndarray, shape (H, W), float32
        Reflectance times shading, 0..1.
    gain, offset : float
        Grey levels per unit radiance, grey-level offset.
    defocus_sigma_px : float
        Gaussian defocus blur, px.
    noise_sigma : float
        Read-noise standard deviation, grey levels; shot noise is added on top.
    rng : numpy.random.Generator
    shot_gain : float
        Shot-noise variance per grey level (at unit analog gain).
    analog_gain : float
        Sensor gain relative to the reference; read noise and shot noise scale with it.
        ``radiance`` may also be (H, W, 3) with ``gain`` per channel (colour).

    Returns
    -------
    image : ndarray, shape (H, W) or (H, W, 3), uint8
    """
    grey = radiance * np.float32(gain) + np.float32(offset)
    if defocus_sigma_px > 0.05:
        grey = cv2.GaussianBlur(grey, (0, 0), float(defocus_sigma_px))
    noise = rng.standard_normal(grey.shape, dtype=np.float32)
    if analog_gain != 1.0:
        noise_sigma, shot_gain = noise_sigma * analog_gain, shot_gain * analog_gain
    sigma = np.sqrt(np.float32(noise_sigma) ** 2 + np.float32(shot_gain) * np.clip(grey, 0, None))
    grey = grey + sigma * noise
    return np.clip(np.rint(grey), 0, 255).astype(np.uint8)
