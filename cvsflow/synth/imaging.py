"""Camera model and image formation of the demo session: projection, lens, background, exposure.

The board itself, its texture and its image, is :mod:`cvsflow.synth.board_image`; this module
holds the board's geometry (``Board``), the projection of board points in view (the lens is
:func:`cvsflow.geometry.distort_normalised`) and its undistortion grid, and the background,
vignetting and exposure the rendered frames go through.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.board import AprilGrid
from cvsflow.geometry import distort_normalised, project_points

A1_SHEET_M = (0.841, 0.594)  # printed sheet, width x height, metres
#: White paper round an AprilGrid's outer corner squares, bits of its tags (the sheet).
APRILGRID_MARGIN_BITS = 6
# Beyond this normalised radius the 5-term polynomial is no longer a physical lens
# (it folds back); rays there are far outside a 640x480 image at f ~ 700 px (r ~ 0.6).
MAX_RAY_RADIUS = 1.2


@dataclass(frozen=True)
class Board:
    """Chessboard geometry in the board frame B (origin at inner corner 0, z into the board).

    Attributes are metres; ``nx``, ``ny`` count inner corners along x and y. ``kind``
    ``"charuco"`` adds ArUco markers of side ``marker_m`` from ``dictionary`` to the white
    squares (``cvsflow.board.charuco``); the squares and corners are the chessboard's.
    ``kind`` ``"aprilgrid"`` is a Kalibr AprilGrid ``grid`` instead (:func:`aprilgrid_board`):
    its corners are the grid's, in Kalibr's frame (z out of the printed face), and
    ``square_m`` is its tag size, the feature a still must show large enough.
    """

    squares_x: int
    squares_y: int
    square_m: float
    kind: str = "chessboard"
    marker_m: float = 0.0
    dictionary: str = ""
    grid: AprilGrid | None = None

    def config(self) -> dict:
        """The board's config block (``board:``): the chessboard's three keys, plus
        ``type``, ``marker_m`` and ``dictionary`` for a ChArUco board; an AprilGrid's keys."""
        if self.kind == "aprilgrid":
            return self.grid.config()
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
        """Inner corners, shape (nx * ny, 3): corner k at ((k % nx) s, (k // nx) s, 0); an
        AprilGrid's corners, shape (4 n_tags, 3), row = corner id."""
        if self.kind == "aprilgrid":
            return self.grid.object_points()
        k = np.arange(self.nx * self.ny)
        return np.stack(
            [(k % self.nx) * self.square_m, (k // self.nx) * self.square_m, 0.0 * k], axis=1
        )

    def edge_pairs(self) -> tuple[np.ndarray, np.ndarray]:
        """Neighbouring corners (rows of :meth:`corners_B`), whose image distance says how large
        the board's features are: the chessboard's grid neighbours, an AprilGrid's tag sides.

        Returns
        -------
        a, b : ndarray, shape (E,), int
        """
        if self.kind == "aprilgrid":
            k = np.arange(self.grid.n_corners)
            return k, 4 * (k // 4) + (k + 1) % 4
        k = np.arange(self.nx * self.ny).reshape(self.ny, self.nx)
        return (np.r_[k[:, :-1].ravel(), k[:-1, :].ravel()], np.r_[k[:, 1:].ravel(), k[1:, :].ravel()])

    def R_face_B(self) -> np.ndarray:
        """Rotation (3, 3) from B to the board's face-on frame (x right, y down the printed face as
        the camera sees it, z away from the camera): identity for a chessboard, a half turn
        about x for an AprilGrid (its z points out of the printed face)."""
        return np.diag([1.0, -1.0, -1.0]) if self.kind == "aprilgrid" else np.eye(3)

    def printed_B(self):
        """Printed squares' extent in B: (x_min, x_max, y_min, y_max), metres (an AprilGrid: its
        tags and corner squares)."""
        if self.kind == "aprilgrid":
            return self.grid.printed_extent_m()
        s = self.square_m
        return (-s, (self.squares_x - 1) * s, -s, (self.squares_y - 1) * s)

    def sheet_B(self):
        """A1 sheet's extent in B, centred on the printed squares: (x0, x1, y0, y1), metres."""
        x0, x1, y0, y1 = self.printed_B()
        if self.kind == "aprilgrid":  # the print and its white margin
            m = APRILGRID_MARGIN_BITS * self.grid.tag_size_m / self.grid.tag_bits
            return (x0 - m, x1 + m, y0 - m, y1 + m)
        cx, cy = 0.5 * (x0 + x1), 0.5 * (y0 + y1)
        w, h = A1_SHEET_M
        return (cx - w / 2, cx + w / 2, cy - h / 2, cy + h / 2)

    def center_B(self) -> np.ndarray:
        """Centre of the inner-corner grid (an AprilGrid's tags), shape (3,), metres."""
        if self.kind == "aprilgrid":
            return self.grid.tag_centres().mean(axis=0)
        return np.array([(self.nx - 1) * self.square_m / 2, (self.ny - 1) * self.square_m / 2, 0])



def aprilgrid_board(grid: AprilGrid) -> Board:
    """The renderer's :class:`Board` of a Kalibr AprilGrid.

    Parameters
    ----------
    grid : AprilGrid

    Returns
    -------
    Board
        ``kind="aprilgrid"``, ``square_m`` its tag size, no chessboard squares.
    """
    return Board(0, 0, float(grid.tag_size_m), kind="aprilgrid", grid=grid)


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


def project_in_view(T_C_B, p_B, K, dist):
    """Pixels of board points seen through the lens, NaN where the lens model does not hold.

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
        :func:`cvsflow.geometry.project_points`' pixels; NaN for points behind the camera or
        on rays outside the lens model's valid domain (normalised radius > ``MAX_RAY_RADIUS``),
        where the polynomial folds back.
    """
    T_C_B = np.asarray(T_C_B, dtype=float)
    p_C = np.einsum("...ij,mj->...mi", T_C_B[..., :3, :3], p_B) + T_C_B[..., None, :3, 3]
    z = p_C[..., 2:3]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = p_C[..., :2] / z
    valid = (z[..., 0] > 1e-6) & (np.sum(xy * xy, axis=-1) < MAX_RAY_RADIUS**2)
    uv = project_points(np.where(valid[..., None], p_C, [0.0, 0.0, 1.0]), K, dist)
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
