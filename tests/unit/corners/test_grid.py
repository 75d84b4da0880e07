"""Tests of cvsflow.corners.grid: the grid's spacing and each corner's deviation from its neighbours."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}  # the demo board, 5x4 inner corners


def test_grid_deviation_is_the_displacement_of_a_misplaced_corner():
    # An exact perspective view of the grid with one corner moved: its neighbours (exact)
    # predict its true place, so its deviation is its displacement; corners farther than two
    # grid steps from it are predicted exactly; a NaN corner predicts nothing.
    from cvsflow.corners.grid import _neighbour_weights, grid_deviation

    board = {"squares_x": 9, "squares_y": 7, "square_m": 0.03}
    nx, ny = 8, 6
    k = np.arange(nx * ny)
    grid = np.stack([k % nx, k // nx], axis=1).astype(np.float64)
    H = np.array([[38.0, 4.0, 120.0], [-3.0, 35.0, 90.0], [4e-3, -6e-3, 1.0]])
    uv = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    moved = uv.copy()
    moved[19] += (1.5, -2.0)
    predicted, dev = grid_deviation(moved, board)
    assert dev[19] == pytest.approx(2.5, abs=1e-6)
    np.testing.assert_allclose(predicted[19], uv[19], atol=1e-6)
    far = _neighbour_weights(nx, ny)[:, 19] == 0
    far[19] = False
    assert dev[far].max() < 1e-6
    assert dev[~far].max() > 1e-3  # its neighbours see it
    moved[19] = np.nan
    _, dev = grid_deviation(moved, board)
    assert np.isinf(dev[19]) and np.delete(dev, 19).max() < 1e-6


def test_sort_median_equals_numpy_median():
    from cvsflow.corners.grid import _median

    rng = np.random.default_rng(3)
    for n in (1, 2, 7, 48, 101):
        x = rng.normal(size=n)
        assert _median(x) == np.median(x)
    x = rng.normal(size=(6, 4))
    assert _median(x) == np.median(x)


def test_grid_deviation_equals_a_least_squares_homography_per_corner():
    # Each corner's prediction is the h33 = 1 least-squares DLT homography of its known
    # neighbours within two grid steps (normalised pixels), solved here row by row with lstsq;
    # a corner whose known neighbours lie on a line gets no prediction (inf).
    from cvsflow.corners.grid import _neighbour_weights, grid_deviation

    board = {"squares_x": 9, "squares_y": 7, "square_m": 0.03}
    nx, ny = 8, 6
    k = np.arange(nx * ny)
    grid = np.stack([k % nx, k // nx], axis=1).astype(np.float64)
    H = np.array([[31.0, 5.0, 140.0], [-4.0, 29.0, 70.0], [3e-3, -5e-3, 1.0]])
    rng = np.random.default_rng(11)
    uv = cv2.perspectiveTransform(grid.reshape(-1, 1, 2), H).reshape(-1, 2)
    uv += rng.normal(scale=0.4, size=uv.shape)
    uv[[5, 17, 18, 30, 44]] = np.nan
    predicted, dev = grid_deviation(uv, board)
    known = np.isfinite(uv).all(axis=1)
    centre = uv[known].mean(axis=0)
    scale = np.sqrt(2.0) / np.linalg.norm(uv[known] - centre, axis=1).mean()
    un = (uv - centre) * scale
    near = _neighbour_weights(nx, ny) > 0
    for c in np.flatnonzero(known):
        rows, rhs = [], []
        for j in np.flatnonzero(near[c] & known):
            x, y = grid[j]
            u, v = un[j]
            rows += [[x, y, 1, 0, 0, 0, -u * x, -u * y], [0, 0, 0, x, y, 1, -v * x, -v * y]]
            rhs += [u, v]
        h = np.append(np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)[0], 1.0)
        p = h.reshape(3, 3) @ np.append(grid[c], 1.0)
        expected = p[:2] / p[2] / scale + centre
        np.testing.assert_allclose(predicted[c], expected, atol=1e-6)
        assert dev[c] == pytest.approx(np.linalg.norm(expected - uv[c]), abs=1e-6)
    assert np.isinf(dev[~known]).all()
    line = np.full_like(uv, np.nan)
    line[:nx] = uv[:nx] if np.isfinite(uv[:nx]).all() else grid[:nx] * 30.0
    assert np.isinf(grid_deviation(line, board)[1]).all()


def test_local_spacing_is_the_mean_distance_to_known_neighbours():
    from cvsflow.corners.grid import local_spacing

    board = {"squares_x": 6, "squares_y": 5, "square_m": 0.03}
    nx, ny = 5, 4
    rng = np.random.default_rng(12)
    uv = rng.normal(scale=40.0, size=(nx * ny, 2))
    uv[[0, 1, 5, 12]] = np.nan
    got = local_spacing(uv, board)
    expected = np.full(nx * ny, np.nan)
    for c in range(nx * ny):
        i, j = c % nx, c // nx
        d = [np.linalg.norm(uv[c] - uv[jj * nx + ii])
             for ii, jj in ((i - 1, j), (i + 1, j), (i, j - 1), (i, j + 1))
             if 0 <= ii < nx and 0 <= jj < ny]
        d = [x for x in d if np.isfinite(x)]
        if d:
            expected[c] = np.mean(d)
    expected[np.isnan(expected)] = np.median(expected[np.isfinite(expected)])
    np.testing.assert_allclose(got, expected, rtol=1e-12)


def test_quadratic_deviation_is_exact_on_quadratic_fields_and_sees_a_moved_corner():
    """A grid whose pixels are quadratic in the grid coordinates (what a lens and perspective
    do over two squares, to second order) is predicted exactly; a corner moved by d deviates
    by d; a corner with fewer than six known neighbours gets no prediction (inf); and the
    map equals an explicit least-squares quadratic per corner."""
    from cvsflow.corners.grid import quadratic_deviation

    board = {"squares_x": 9, "squares_y": 7, "square_m": 0.03}
    nx, ny = 8, 6
    k = np.arange(nx * ny)
    x, y = (k % nx).astype(float), (k // nx).astype(float)
    uv = np.stack([100 + 30 * x + 0.6 * x * x + 0.4 * x * y - 0.2 * y * y + 2 * y,
                   80 + 28 * y - 0.5 * y * y + 0.3 * x * y + 0.1 * x * x + x], axis=1)
    assert quadratic_deviation(uv, board).max() < 1e-9
    moved = uv.copy()
    moved[19] += (1.5, -2.0)
    assert quadratic_deviation(moved, board)[19] == pytest.approx(2.5, abs=1e-9)
    # Hidden corners: a 3x2 block around corner 19 and the whole first row.
    hidden = uv.copy()
    hidden[[18, 19, 20, 26, 27, 28]] = np.nan
    hidden[:nx] = np.nan
    rng = np.random.default_rng(3)
    noisy = hidden + rng.normal(0.0, 0.2, hidden.shape)
    dev = quadratic_deviation(noisy, board)
    assert np.isinf(dev[np.isnan(hidden[:, 0])]).all()
    for i in np.flatnonzero(np.isfinite(hidden[:, 0])):
        nb = [j for j in range(nx * ny) if j != i and abs(x[j] - x[i]) <= 2
              and abs(y[j] - y[i]) <= 2 and np.isfinite(hidden[j, 0])]
        dx, dy = x[nb] - x[i], y[nb] - y[i]
        A = np.stack([np.ones_like(dx), dx, dy, dx * dx, dx * dy, dy * dy], axis=1)
        if len(nb) < 6 or np.linalg.matrix_rank(A) < 6:
            assert np.isinf(dev[i])
            continue
        coef = np.linalg.lstsq(A, noisy[nb], rcond=None)[0]
        assert dev[i] == pytest.approx(np.linalg.norm(noisy[i] - coef[0]), abs=1e-9)
    assert np.isfinite(dev).sum() >= 20
