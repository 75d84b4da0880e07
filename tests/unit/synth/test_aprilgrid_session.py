"""A rendered session with an AprilGrid: the grid faces the camera in every still and frame (its
z points out of the printed face), its corners are the grid's, and a hand is refused."""

import numpy as np
import pytest
import yaml

from cvsflow.exceptions import ConfigError
from cvsflow.synth.motion import board_poses, make_hand_motion, still_poses
from cvsflow.synth.session import still_outline_B
from cvsflow.synth.spec import parse_session_config
from tests.helpers.real_data import REPO


def aprilgrid_session():
    return yaml.safe_load((REPO / "config" / "aprilgrid.yaml").read_text())["sessions"]["aprilgrid"]


def test_stills_and_video_show_the_printed_face():
    """Every still and video pose has the grid in front of the camera with z_B towards it."""
    spec = parse_session_config(aprilgrid_session())
    board = spec.board
    assert board.kind == "aprilgrid" and board.corners_B().shape == (144, 3)
    rng = np.random.default_rng(0)
    T = still_poses(rng, 6, spec.K, spec.dist, spec.image_size, still_outline_B(board), board=board)
    assert len(T) == 6 and np.all(T[:, 2, 2] < 0) and np.all(T[:, 2, 3] > 0)
    motion = make_hand_motion(rng, spec.K, spec.image_size, board.center_B(), (0.7, 1.6),
                              R_face_B=board.R_face_B())
    T = board_poses(motion, np.linspace(0.0, 8.0, 50))
    assert np.all(T[:, 2, 2] < 0) and np.all(T[:, 2, 3] > 0)


def test_tag_sides_are_the_feature_edges():
    """edge_pairs of an AprilGrid are its tags' four sides, each tag_size_m long."""
    board = parse_session_config(aprilgrid_session()).board
    a, b = board.edge_pairs()
    p = board.corners_B()
    np.testing.assert_allclose(np.linalg.norm(p[a] - p[b], axis=1), 0.055)


def test_a_hand_over_an_aprilgrid_is_refused():
    """occlusion (the hand) is drawn over chessboard squares only: a named ConfigError."""
    cfg = aprilgrid_session()
    cfg["synth"]["occlusion"] = {"enabled": True}
    with pytest.raises(ConfigError, match="occlusion"):
        parse_session_config(cfg)
