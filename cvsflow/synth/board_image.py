"""The board's texture and its image in the camera, for the demo session's renderer.

The board is rendered in one resampling step per instant: for every pixel of the distorted
image, its undistorted normalised ray (computed once per camera,
:func:`cvsflow.synth.imaging.undistortion_grid`) is mapped by the plane homography into the
board texture, and the pixel's value is the texture's exact mean over the pixel's footprint
there (an axis-aligned box in texel space read from the finest level's summed-area table,
:func:`render_board_region`). Far boards are so free of aliasing, and an edge's image does not
depend on where it falls on the texel grid. Motion blur is the mean of several such renders
over the exposure time.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.board import AprilGrid, charuco_board
from cvsflow.geometry import invert_T
from cvsflow.synth.imaging import APRILGRID_MARGIN_BITS, Board, project_in_view, rectangle_outline_B

INK_REFLECTANCE = 0.06
MARKER_RADIUS_M = 0.007  # 14 mm Vicon marker
PAPER_REFLECTANCE = 0.88


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
    sums: np.ndarray | None = None  # (rows + 1, cols + 1, 2) float64 summed-area table of levels[0]


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
        square edges and one empty texel ring round the sheet (an AprilGrid: its own texels
        on its bit edges, :func:`aprilgrid_texture`).
    """
    if board.kind == "aprilgrid":
        return aprilgrid_texture(board.grid, margin_bits=APRILGRID_MARGIN_BITS, markers_B=markers_B)
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


def tag_bits_image(tag_id: int, grid: AprilGrid,
                   dictionary: int = cv2.aruco.DICT_APRILTAG_36h11) -> np.ndarray:
    """A tag's bits as printed on a Kalibr AprilGrid, seen from the printed face, rows downward.

    Parameters
    ----------
    tag_id : int
        Id in ``dictionary`` (any id of it: a tag of another grid can be drawn).
    grid : AprilGrid
        ``border_bits`` is used.
    dictionary : int
        ``cv2.aruco`` predefined dictionary of the tag (``DICT_APRILTAG_36h11`` is tag36h11).

    Returns
    -------
    bits : ndarray, shape (n, n), bool
        True for white; ``n = data bits + 2 border_bits``; image rows run along B's -y.
    """
    d = cv2.aruco.getPredefinedDictionary(dictionary)
    n_data = d.markerSize
    marker = cv2.aruco.generateImageMarker(d, int(tag_id), n_data + 2, borderBits=1)
    b = grid.border_bits
    bits = np.zeros((n_data + 2 * b,) * 2, dtype=bool)
    # Kalibr's kalibr_create_target_pdf draws the code turned by 180 degrees against cv2.aruco.
    bits[b:b + n_data, b:b + n_data] = np.rot90(marker[1:-1, 1:-1] > 127, 2)
    return bits


def aprilgrid_texture(grid: AprilGrid, texels_per_bit: int = 12, margin_bits: int = 6,
                      tags: dict | None = None, ink_spread_bits: float = 0.0, n_levels: int = 4,
                      markers_B=None) -> BoardTexture:
    """Texture of a printed Kalibr AprilGrid, for :func:`render_board`.

    The grid as ``kalibr_create_target_pdf`` prints it: each tag a black square of
    ``tag_bits`` bits (:func:`tag_bits_image`) and a black square of side
    ``tag_spacing * tag_size_m`` at each of its corners, on white paper. Texel edges fall on
    bit edges, so every tag corner is exact in the texture. Texture rows run along B's +y.

    Parameters
    ----------
    grid : AprilGrid
    texels_per_bit : int
        Texels across one bit (the gaps are rounded to texels: whole for Kalibr's 0.3).
    margin_bits : int
        White paper round the outer corner squares, bits.
    tags : dict, optional
        ``{tag_id: bits}`` replacing the pattern of some tags (``bits`` as from
        :func:`tag_bits_image`): a mirrored tag, a tag of another grid, for tests.
    ink_spread_bits : float
        Every black region grows by this much on each side (negative: shrinks), bits, rounded
        to texels. At 0 a tag and its corner squares meet in a point; above 0 they overlap (ink
        spread), below 0 a white path separates them. The X junction, the true corner, stays.
    n_levels : int
        Texture pyramid levels.
    markers_B : ndarray, shape (M, 3), optional
        Motion-capture markers stuck on the sheet (frame B, metres), drawn as grey discs.

    Returns
    -------
    texture : BoardTexture
        Texel (c, r) has its centre at B = (x0 + (c + 0.5) / ppm, y0 + (r + 0.5) / ppm).
    """
    n_bits = grid.tag_bits
    ppm = texels_per_bit * n_bits / grid.tag_size_m
    gap_tex = int(round(grid.tag_spacing * n_bits * texels_per_bit))
    tag_tex = n_bits * texels_per_bit
    pitch_tex = tag_tex + gap_tex
    pad = gap_tex + margin_bits * texels_per_bit
    step = 2 ** (n_levels - 1)
    cols = -(-(grid.tag_cols * pitch_tex - gap_tex + 2 * pad) // step) * step
    rows = -(-(grid.tag_rows * pitch_tex - gap_tex + 2 * pad) // step) * step
    white = np.ones((rows, cols), dtype=bool)
    tags = tags or {}
    for t in range(grid.n_tags):
        r0 = pad + (t // grid.tag_cols) * pitch_tex
        c0 = pad + (t % grid.tag_cols) * pitch_tex
        bits = tags.get(t, tag_bits_image(t, grid))
        # texture rows run along +y: the face view (rows along -y) upside down
        white[r0:r0 + tag_tex, c0:c0 + tag_tex] = np.kron(
            np.flipud(bits), np.ones((texels_per_bit, texels_per_bit), dtype=bool))
        for dr in (-gap_tex, tag_tex):
            for dc in (-gap_tex, tag_tex):
                white[r0 + dr:r0 + dr + gap_tex, c0 + dc:c0 + dc + gap_tex] = False
    spread = int(round(abs(ink_spread_bits) * texels_per_bit))
    if spread:
        kernel = np.ones((2 * spread + 1, 2 * spread + 1), np.uint8)
        grow = cv2.erode if ink_spread_bits > 0 else cv2.dilate
        white = grow(white.astype(np.uint8), kernel, borderType=cv2.BORDER_REPLICATE).astype(bool)
    x0 = -pad / ppm
    reflectance = np.where(white, PAPER_REFLECTANCE, INK_REFLECTANCE).astype(np.float32)
    if markers_B is not None:
        reflectance = _draw_markers(reflectance, markers_B, x0, x0, ppm,
                                    (x0, x0 + cols / ppm, x0, x0 + rows / ppm))
    level = np.dstack([reflectance, np.ones_like(reflectance)])
    return texture_pyramid(level, ppm, n_levels, x0, x0)


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
        Level l at ``ppm / 2**l`` texels per metre, and ``sums``, the summed-area table of
        ``level`` (``sums[j, i]`` = sum of texels [0, j) x [0, i)) that the renderer reads.
    """
    levels, ppms = [level], [ppm]
    for _ in range(n_levels - 1):
        level = cv2.resize(level, None, fx=0.5, fy=0.5, interpolation=cv2.INTER_AREA)
        levels.append(level)
        ppms.append(ppms[-1] / 2)
    sums = cv2.integral(levels[0].astype(np.float64), sdepth=cv2.CV_64F)
    return BoardTexture(tuple(levels), tuple(ppms), float(x0), float(y0), sums)


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


# Box corners are rounded to 1 / REMAP_STEPS texel before cv2.remap reads the summed-area
# table: OpenCV's bilinear remap works on that grid (INTER_BITS = 5) whatever the map's
# precision, so the box that is summed is exactly the one whose area divides the sum.
REMAP_STEPS = 32
# Box half-sizes are held in [1 / REMAP_STEPS, MAX_BOX_TEXELS] texels (a board seen nearly
# edge-on has enormous footprints near its horizon: they are averaged over at most this).
MAX_BOX_TEXELS = 256.0


def render_board_region(T_C_B, texture: BoardTexture, xy_n, K, roi):
    """``render_board`` inside the pixel box ``roi`` = (x0, y0, x1, y1) only: shape (y1-y0, x1-x0, 2).

    Each pixel is the mean of the texture's finest level over a box in texel space: centred
    on the pixel centre's texel position, with the half-widths of the pixel footprint's
    second moments (the footprint is the unit pixel square through the local Jacobian of the
    pixel-to-texel map: the distortion's ray Jacobian from the grid, the plane homography's
    exactly). The box's sum comes from the summed-area table (:attr:`BoardTexture.sums`),
    which is bilinear inside each texel, so four bilinear lookups give it exactly at any
    sub-texel position. For a footprint aligned with the board's axes the value is the exact
    area coverage; a rotated footprint is replaced by a box of its second moments (a
    symmetric change of the pixel's aperture, which moves no edge). A single point sample of
    a mip level instead moved an edge by up to ~0.09 texel with its phase on that level's
    grid, an error shared by every corner of a frame (docs/findings.md, 2026-12-02).

    Parameters
    ----------
    T_C_B : ndarray, shape (4, 4)
        Board in camera, metres.
    texture : BoardTexture
    xy_n : ndarray, shape (H, W, 2)
        ``undistortion_grid`` of the camera. Its rays and their pixel Jacobian are cached
        per grid object (the last four): do not change a grid in place once rendered with.
    K : ndarray, shape (3, 3)
        Camera matrix, px (unused: the pixel footprint comes from ``xy_n``; kept so that
        every renderer call has the camera).
    roi : (int, int, int, int)
        ``(x0, y0, x1, y1)``, pixels, end-exclusive, inside the image.

    Returns
    -------
    layer : ndarray, shape (y1 - y0, x1 - x0, 2), float32
        Channel 0 reflectance times coverage, channel 1 coverage (0..1), pixel-area means;
        0 where the pixel centre's ray misses the sheet or meets the board plane behind the
        camera.
    """
    x0, y0, x1, y1 = roi
    sums = texture.sums
    if sums is None:
        sums = cv2.integral(texture.levels[0].astype(np.float64), sdepth=cv2.CV_64F)
    G = _texel_from_ray(T_C_B, texture, 0).astype(np.float32)
    planes = _grid_planes(xy_n)  # rx, ry, d(rx, ry)/du, d(rx, ry)/dv: (6, H, W) float32
    rx, ry, xu, yu, xv, yv = planes[:, y0:y1, x0:x1]
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        inv = 1.0 / (G[2, 0] * rx + G[2, 1] * ry + G[2, 2])
        map_c = (G[0, 0] * rx + G[0, 1] * ry + G[0, 2]) * inv
        map_r = (G[1, 0] * rx + G[1, 1] * ry + G[1, 2]) * inv
        # d(texel)/d(ray) of the homography, then through the ray's pixel Jacobian; the box
        # half-widths are those of the unit pixel square footprint's second moments
        half = []
        for m, g0, g1 in ((map_c, G[0, 0], G[0, 1]), (map_r, G[1, 0], G[1, 1])):
            a0, a1 = (g0 - m * G[2, 0]) * inv, (g1 - m * G[2, 1]) * inv
            du, dv = a0 * xu + a1 * yu, a0 * xv + a1 * yv
            half.append(0.5 * np.sqrt(du * du + dv * dv))  # not hypot: libm's may vary
        half_c, half_r = half
    # Rays that meet the board plane behind the camera (or nowhere) must sample nothing.
    n_C = T_C_B[:3, 2].astype(np.float32)
    front = (n_C[0] * rx + n_C[1] * ry + n_C[2]) * np.float32(n_C @ T_C_B[:3, 3].astype(np.float32)) > 0
    ok = front & np.isfinite(map_c) & np.isfinite(map_r) & np.isfinite(half_c) & np.isfinite(half_r)
    rows, cols = texture.levels[0].shape[:2]
    far = -4.0 * MAX_BOX_TEXELS
    lo, q = 1.0 / REMAP_STEPS, np.float32(REMAP_STEPS)
    h, w = rx.shape
    map_x = np.empty((4, h, w), np.float32)
    map_y = np.empty((4, h, w), np.float32)
    # texel-centre coordinate c is summed-area coordinate c + 0.5 (texel k spans [k, k + 1))
    for centre, half, size, out, order in ((map_c, half_c, cols, map_x, (0, 1, 0, 1)),
                                           (map_r, half_r, rows, map_y, (0, 0, 1, 1))):
        centre = np.where(ok, np.clip(centre, far, size - far), far) + np.float32(0.5)
        half = np.clip(np.where(ok, half, lo), lo, MAX_BOX_TEXELS)
        ends = (np.rint((centre - half) * q) / q, np.rint((centre + half) * q) / q)
        for k, e in enumerate(order):
            out[k] = ends[e]
    s = cv2.remap(sums, map_x.reshape(4 * h, w), map_y.reshape(4 * h, w),
                  interpolation=cv2.INTER_LINEAR,
                  borderMode=cv2.BORDER_REPLICATE).reshape(4, h, w, 2)
    area = (map_x[1] - map_x[0]) * (map_y[2] - map_y[0])
    scale = np.where(ok & (area > 0), 1.0 / np.maximum(area, lo * lo), 0.0)[..., None]
    return ((s[3] - s[1] - s[2] + s[0]) * scale).astype(np.float32)


# Undistortion grids seen lately and their planes (_grid_planes), matched by identity: a
# renderer passes the same grid for every frame.
_GRID_PLANES: list = []


def _grid_planes(xy_n):
    """(6, H, W) float32: the grid's rays x, y and their derivatives along u then v (x_u, y_u,
    x_v, y_v, per px; central differences, one-sided at the image border), cached per grid."""
    for grid, planes in _GRID_PLANES:
        if grid is xy_n:
            return planes
    du = np.gradient(xy_n, axis=1) if xy_n.shape[1] > 1 else np.zeros_like(xy_n)
    dv = np.gradient(xy_n, axis=0) if xy_n.shape[0] > 1 else np.zeros_like(xy_n)
    planes = np.stack([xy_n[..., 0], xy_n[..., 1], du[..., 0], du[..., 1], dv[..., 0],
                       dv[..., 1]]).astype(np.float32)
    _GRID_PLANES.insert(0, (xy_n, planes))
    del _GRID_PLANES[4:]
    return planes


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
    uv = project_in_view(T_C_B, outline, K, dist)
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
