"""AprilGrids: Kalibr's geometry and ids, and detection against rendered truth (ids exact, corner
error, partial grids, never a wrong id or corner order: mirrored images, foreign, turned and
repeated tags)."""

import cv2
import numpy as np
import pytest

from cvsflow.board import AprilGrid, aprilgrid_from_board, board_object_points, detect_aprilgrid
from cvsflow.board import aprilgrid_tags as tags
from cvsflow.board.aprilgrid_detect import consistent_tags
from cvsflow.exceptions import ConfigError
from cvsflow.synth.board_image import aprilgrid_texture, tag_bits_image
from cvsflow.synth.imaging import project_in_view, undistortion_grid
from tests.helpers.aprilgrid_images import DIST, GRID, SIZE, K, look_at_grid, render_aprilgrid

# A tag side is >= 20 px in these renders: a corner this far from its truth would be mislabelled.
WRONG_PX = 2.0

# ----------------------------------------------------------------------------- geometry


def test_object_points_follow_kalibr_layout():
    """Tag 0 at the origin, corners counter-clockwise from the bottom-left, ids row-major."""
    p_B = GRID.object_points()
    assert p_B.shape == (144, 3) and np.all(p_B[:, 2] == 0.0)
    s, p = 0.088, 0.088 * 1.3
    np.testing.assert_allclose(p_B[0:4, :2], [[0, 0], [s, 0], [s, s], [0, s]], atol=1e-15)
    np.testing.assert_allclose(p_B[4:8, :2] - p_B[0:4, :2], [[p, 0]] * 4, atol=1e-15)
    np.testing.assert_allclose(p_B[24:28, :2] - p_B[0:4, :2], [[0, p]] * 4, atol=1e-15)
    np.testing.assert_allclose(p_B[143, :2], [5 * p, 5 * p + s], atol=1e-15)
    np.testing.assert_allclose(GRID.tag_centres()[7, :2], [p + s / 2, p + s / 2])


def test_kalibr_point_index_matches_kalibr():
    """Kalibr's 2x2 diagram (GridCalibrationTargetAprilgrid) and its createGridPoints formula."""
    grid = AprilGrid(2, 2, 0.1, 0.25)
    np.testing.assert_array_equal(grid.kalibr_point_index(np.arange(16)),
                                  [0, 1, 5, 4, 2, 3, 7, 6, 8, 9, 13, 12, 10, 11, 15, 14])
    grid = AprilGrid(4, 3, 0.05, 0.2)
    r, c = np.divmod(np.arange(4 * grid.tag_rows * grid.tag_cols), 2 * grid.tag_cols)
    s, sp = grid.tag_size_m, grid.tag_spacing
    kalibr = np.stack([(c // 2) * (1 + sp) * s + (c % 2) * s, (r // 2) * (1 + sp) * s + (r % 2) * s], 1)
    np.testing.assert_allclose(grid.object_points()[:, :2],
                               kalibr[grid.kalibr_point_index(np.arange(grid.n_corners))], atol=1e-15)


def test_board_block_round_trip_and_object_points():
    """board: {type: aprilgrid, ...} gives the grid, and board_object_points its points."""
    board = GRID.config()
    assert board == {"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_size_m": 0.088,
                     "tag_spacing": 0.3}
    assert aprilgrid_from_board(board) == GRID
    np.testing.assert_array_equal(board_object_points(board), GRID.object_points())


@pytest.mark.parametrize("kwargs, match", [
    (dict(tag_cols=0), "tag_cols"), (dict(tag_rows=True), "tag_rows"),
    (dict(tag_size_m=-0.1), "tag_size_m"), (dict(tag_spacing=0.0), "tag_spacing"),
    (dict(tag_spacing=26.4), "not a gap in metres"), (dict(family="tag25h9"), "family"),
    (dict(tag_cols=1, tag_rows=2), "at least"), (dict(tag_cols=30, tag_rows=30), "587"),
])
def test_invalid_grid_is_a_named_config_error(kwargs, match):
    """Each out-of-range value is named."""
    with pytest.raises(ConfigError, match=match):
        AprilGrid(**(dict(tag_cols=6, tag_rows=6, tag_size_m=0.088, tag_spacing=0.3) | kwargs))


def test_board_block_errors_name_the_key():
    """A missing key, a foreign key and a bad value in the board block."""
    with pytest.raises(ConfigError, match="tag_spacing"):
        aprilgrid_from_board({"type": "aprilgrid", "tag_cols": 6, "tag_rows": 6, "tag_size_m": 0.088})
    with pytest.raises(ConfigError, match="square_m"):
        aprilgrid_from_board(GRID.config() | {"square_m": 0.1})
    with pytest.raises(ConfigError, match="board: AprilGrid: tag_size_m"):
        aprilgrid_from_board(GRID.config() | {"tag_size_m": 0})


# ----------------------------------------------------------------------------- detection


@pytest.fixture(scope="module")
def xy_n():
    return undistortion_grid(K, DIST, SIZE)


@pytest.fixture(scope="module")
def textures():
    return {s: aprilgrid_texture(GRID, ink_spread_bits=s) for s in (-0.1, 0.0, 0.1)}


def render(textures, xy_n, spread=-0.1, seed=0, **pose):
    pose = dict(distance_m=1.2, tilt_deg=20.0, tilt_axis_deg=30.0, roll_deg=10.0) | pose
    return render_aprilgrid(look_at_grid(GRID, **pose), texture=textures[spread], xy_n=xy_n, seed=seed)


def errors(ids, uv_px, truth):
    return np.linalg.norm(uv_px - truth[ids], axis=1)


@pytest.mark.parametrize("spread", [-0.1, 0.0, 0.1])
def test_whole_grid_every_junction_topology(textures, xy_n, spread):
    """Corner squares short of the tags, touching them (Kalibr's PDF), overlapping them (ink):
    nearly every tag found, corners within a few hundredths of a pixel."""
    gray, truth = render(textures, xy_n, spread, distance_m=1.1, tilt_deg=15.0)
    stats = {}
    ids, uv = detect_aprilgrid(gray, GRID, stats=stats)
    assert len(np.unique(ids // 4)) >= 33, stats
    assert np.all(np.diff(ids) > 0)
    e = errors(ids, uv, truth)
    assert np.median(e) < 0.06 and e.max() < 0.3, (np.median(e), e.max())


def test_partial_grid_keeps_true_ids(textures, xy_n):
    """A grid cut by the image border keeps its corners under their own ids."""
    gray, truth = render(textures, xy_n, offset_m=(0.5, 0.25), distance_m=1.3)
    ids, uv = detect_aprilgrid(gray, GRID)
    inside = (np.isfinite(truth).all(axis=1) & (truth >= 6).all(axis=1)
              & (truth <= np.array(SIZE) - 7).all(axis=1))
    whole_tags = inside.reshape(-1, 4).all(axis=1)
    assert 8 <= whole_tags.sum() < GRID.n_tags
    found_tags = np.unique(ids // 4)
    assert np.isin(found_tags, np.flatnonzero(inside.reshape(-1, 4).any(axis=1))).all()
    assert np.isin(np.flatnonzero(whole_tags), found_tags).mean() >= 0.8
    assert errors(ids, uv, truth).max() < 0.3


@pytest.mark.parametrize("flip", [1, 0])
def test_mirrored_image_gives_nothing(textures, xy_n, flip):
    """A mirror image of the grid (left-right, top-bottom) is refused whole."""
    gray, _ = render(textures, xy_n)
    assert len(detect_aprilgrid(gray, GRID)[0]) > 100
    stats = {}
    ids, uv = detect_aprilgrid(cv2.flip(gray, flip), GRID, stats=stats)
    assert len(ids) == 0 and uv.shape == (0, 2), stats


def test_foreign_turned_and_repeated_tags_are_dropped(xy_n):
    """A tag of another grid, a turned tag, a second copy of an id and a mirrored tag are all
    dropped; the real tag of the repeated id is kept, every kept corner is right."""
    bits = {
        7: tag_bits_image(100, GRID),  # a tag36h11 id outside the 6x6 grid
        14: np.rot90(tag_bits_image(14, GRID)),  # tag 14 turned 90 degrees in its place
        20: tag_bits_image(8, GRID),  # a second tag 8, in tag 20's place
        27: np.fliplr(tag_bits_image(27, GRID)),  # tag 27 mirrored
    }
    texture = aprilgrid_texture(GRID, tags=bits, ink_spread_bits=-0.1)
    gray, truth = render({-0.1: texture}, xy_n)
    stats = {}
    ids, uv = detect_aprilgrid(gray, GRID, stats=stats)
    found = set(np.unique(ids // 4).tolist())
    assert not found & {7, 14, 20, 27}, stats
    assert 8 in found and len(found) >= 30
    assert errors(ids, uv, truth).max() < 0.3
    assert stats["not_in_grid"] >= 1 and stats["duplicate"] >= 1


def test_aruco_fallback_passes(textures, xy_n):
    """The ArUco-only detector (no pupil-apriltags) finds the grid with the same accuracy."""
    gray, truth = render(textures, xy_n, spread=0.1, distance_m=1.0, tilt_deg=10.0)
    ids, uv = detect_aprilgrid(gray, GRID, passes=tags.ARUCO_PASSES)
    assert len(np.unique(ids // 4)) >= 30
    assert errors(ids, uv, truth).max() < 0.3


def test_without_pupil_apriltags_falls_back_with_a_warning(monkeypatch, caplog):
    """Where pupil-apriltags cannot be imported the default is ArUco alone, said in the log and
    in the detector's name; an explicit AprilTag pass is an ImportError saying what to do."""
    monkeypatch.setattr(tags, "pupil_apriltags", None)
    tags._warn_fallback.cache_clear()
    tags._apriltag_detector.cache_clear()
    with caplog.at_level("WARNING"):
        assert tags.default_passes() == tags.ARUCO_PASSES
    assert "pupil-apriltags is not installed" in caplog.text
    assert tags.passes_name(tags.default_passes()).startswith("aruco (opencv")
    with pytest.raises(ImportError, match="passes=\\(ArucoPass\\(\\),\\)"):
        tags.detect_tags(np.zeros((48, 64), np.uint8), GRID, (tags.AprilTagPass(),))
    tags._apriltag_detector.cache_clear()


def test_detector_name_says_what_ran():
    """The default detector's name carries both libraries and their versions."""
    name = tags.passes_name(tags.APRILTAG_PASSES)
    assert name.startswith("apriltag3 x2 + aruco (pupil-apriltags ") and cv2.__version__ in name


def test_too_few_tags_gives_nothing(textures, xy_n):
    """Fewer consistent tags than min_tags: no corner at all."""
    gray, _ = render(textures, xy_n, offset_m=(0.62, 0.42), distance_m=1.2, tilt_deg=0.0, roll_deg=0.0)
    n_tags = len(np.unique(detect_aprilgrid(gray, GRID)[0] // 4))
    assert 4 <= n_tags < 12
    stats = {}
    ids, _ = detect_aprilgrid(gray, GRID, min_tags=n_tags + 1, stats=stats)
    assert len(ids) == 0 and stats["too_few"] == n_tags


def test_rejects_colour_image():
    with pytest.raises(ValueError, match="uint8"):
        detect_aprilgrid(np.zeros((48, 64, 3), np.uint8), GRID)


def truth_detections():
    """Every tag's true corners (Kalibr order) of a well-seen grid: (ids, corners)."""
    uv = project_in_view(look_at_grid(GRID, 1.2, 20.0, 30.0, 10.0), GRID.object_points(), K, DIST)
    return np.arange(GRID.n_tags), uv.reshape(-1, 4, 2)


def test_consistent_tags_drops_each_kind_of_wrong_detection():
    """Swapped ids, turned and mirrored corner orders, an out-of-grid id and a duplicate: exactly
    those are dropped, each counted under its reason."""
    ids, quads = truth_detections()
    ids, quads = ids.copy(), quads.copy()
    ids[[3, 4]] = ids[[4, 3]]
    quads[10] = np.roll(quads[10], 1, axis=0)
    quads[11] = quads[11][::-1]
    ids[12] = 40
    ids[30] = 13
    stats = {}
    keep = consistent_tags(ids, quads, GRID, stats=stats)
    dropped = {3, 4, 10, 11, 12, 30}
    assert set(np.flatnonzero(~keep).tolist()) == dropped, stats
    assert stats == dict(not_in_grid=1, duplicate=1, winding=1, mirrored=0, off_grid=3, too_few=0,
                         kept=GRID.n_tags - len(dropped))


def test_consistent_tags_rejects_a_mirrored_layout_and_needs_min_tags():
    """A mirrored layout whose tags each wind the right way is refused; 4 tags are enough, 3 not."""
    ids, quads = truth_detections()
    mirrored = quads.copy()
    mirrored[..., 0] = SIZE[0] - 1 - mirrored[..., 0]
    assert not consistent_tags(ids, mirrored[:, [1, 0, 3, 2]], GRID).any()
    assert consistent_tags(ids[:4], quads[:4], GRID).all()
    assert not consistent_tags(ids[:3], quads[:3], GRID).any()
    with pytest.raises(ValueError, match="min_tags"):
        consistent_tags(ids, quads, GRID, min_tags=2)


def test_each_backend_returns_kalibr_corner_order(textures, xy_n):
    """AprilTag 3 and ArUco raw corners both come in Kalibr's k order (a wrong order would put
    them a side, ~50 px, away; the raw corners are edge intersections, so only order is checked)."""
    gray, truth = render(textures, xy_n, spread=-0.1, distance_m=1.0, tilt_deg=10.0)
    for p in (tags.AprilTagPass(upsample=1, quad_decimate=1.0), tags.AprilTagPass(), tags.ArucoPass()):
        tag_ids, quads = tags.detect_tags(gray, GRID, (p,))
        assert len(tag_ids) >= 20, p
        true_quads = truth.reshape(-1, 4, 2)[tag_ids]
        side = np.linalg.norm(true_quads - np.roll(true_quads, 1, axis=1), axis=-1).min()
        assert np.linalg.norm(quads - true_quads, axis=-1).max() < 0.1 * side, p
