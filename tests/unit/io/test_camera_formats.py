"""Interchange files read back by their own readers and compared with camera.yaml."""

import logging

import cv2
import numpy as np
import pytest
import yaml

from cvsflow.exceptions import InputError
from cvsflow.geometry.transforms import R_from_euler, invert_T, make_T
from cvsflow.io.camera_formats import (
    K3_WARN_PX,
    k3_drop_shift_px,
    write_all_formats,
    write_camera_format,
    write_kalibr_rig_camchain,
)

CAMERA = {
    "K": [[702.1, 0.0, 331.4], [0.0, 698.3, 247.2], [0.0, 0.0, 1.0]],
    "dist": [-0.12, 0.09, 0.0009, -0.0007, -0.02],
    "width": 640,
    "height": 480,
    "rms_px": 0.21,
    "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
}


@pytest.fixture
def files(tmp_path):
    return write_all_formats(CAMERA, tmp_path)


def test_opencv_filestorage_round_trip(files):
    fs = cv2.FileStorage(str(files["opencv"]), cv2.FILE_STORAGE_READ)
    K = fs.getNode("camera_matrix").mat()
    dist = fs.getNode("distortion_coefficients").mat().ravel()
    assert int(fs.getNode("image_width").real()) == 640
    assert int(fs.getNode("image_height").real()) == 480
    fs.release()
    np.testing.assert_allclose(K, CAMERA["K"], rtol=0, atol=1e-12)
    np.testing.assert_allclose(dist, CAMERA["dist"], rtol=0, atol=1e-15)


def test_kalibr_camchain_keys_and_values(files):
    data = yaml.safe_load(files["kalibr"].read_text())
    cam = data["cam0"]
    assert cam["camera_model"] == "pinhole" and cam["distortion_model"] == "radtan"
    fu, fv, pu, pv = cam["intrinsics"]
    K = np.asarray(CAMERA["K"])
    np.testing.assert_allclose([fu, fv, pu, pv], [K[0, 0], K[1, 1], K[0, 2], K[1, 2]])
    np.testing.assert_allclose(cam["distortion_coeffs"], CAMERA["dist"][:4])
    assert cam["resolution"] == [640, 480]
    text = files["kalibr"].read_text()
    assert "k3" in text and "inner corners" in text


def test_ros_camera_info_keys_and_values(files):
    data = yaml.safe_load(files["ros"].read_text())
    # The keys camera_calibration_parsers (parse_yml.cpp) reads.
    for key in ("image_width", "image_height", "camera_name", "camera_matrix", "distortion_model",
                "distortion_coefficients", "rectification_matrix", "projection_matrix"):
        assert key in data
    K = np.asarray(data["camera_matrix"]["data"]).reshape(data["camera_matrix"]["rows"], 3)
    np.testing.assert_allclose(K, CAMERA["K"])
    assert data["distortion_model"] == "plumb_bob"
    np.testing.assert_allclose(data["distortion_coefficients"]["data"], CAMERA["dist"])
    np.testing.assert_allclose(np.reshape(data["rectification_matrix"]["data"], (3, 3)), np.eye(3))
    P = np.reshape(data["projection_matrix"]["data"], (3, 4))
    np.testing.assert_allclose(P[:, :3], CAMERA["K"])
    np.testing.assert_allclose(P[:, 3], 0.0)


def test_every_file_states_the_board_convention(files):
    for path in files.values():
        assert "inner corners" in path.read_text(), path


def test_k3_shift_zero_without_k3_and_warned_when_large(tmp_path, caplog):
    cam0 = dict(CAMERA, dist=CAMERA["dist"][:4] + [0.0])
    assert k3_drop_shift_px(cam0) < 1e-6
    shift = k3_drop_shift_px(CAMERA)
    # k3 = -0.02 at the corner (r^2 ~ 0.35 in normalised units) moves a pixel ~ 0.6 px.
    assert shift > K3_WARN_PX
    with caplog.at_level(logging.WARNING, logger="cvsflow.io.camera_formats"):
        write_camera_format(CAMERA, "kalibr", tmp_path / "c.yaml")
    assert any("k3" in r.message for r in caplog.records)


def test_unknown_format_and_bad_camera_are_named(tmp_path):
    with pytest.raises(InputError, match="format"):
        write_camera_format(CAMERA, "matlab", tmp_path / "x")
    with pytest.raises(InputError, match="dist"):
        write_camera_format(dict(CAMERA, dist=[0.1, 0.2]), "ros", tmp_path / "x")


def test_kalibr_rig_camchain_chains_the_transforms(tmp_path):
    T_C1_C0 = invert_T(make_T(R_from_euler([0.0, -0.2, 0.0]), [1.0, 0.0, 0.05]))
    T_C2_C0 = invert_T(make_T(R_from_euler([0.0, 0.1, 0.02]), [-0.5, 0.01, 0.0]))
    path = tmp_path / "rig.yaml"
    shifts = write_kalibr_rig_camchain([CAMERA, CAMERA, CAMERA], [T_C1_C0, T_C2_C0], path)
    data = yaml.safe_load(path.read_text())
    assert list(data) == ["cam0", "cam1", "cam2"] and len(shifts) == 3
    assert "T_cn_cnm1" not in data["cam0"]
    T10 = np.array(data["cam1"]["T_cn_cnm1"])
    T21 = np.array(data["cam2"]["T_cn_cnm1"])
    assert np.allclose(T10, T_C1_C0)
    # chaining the file's transforms gives camera 2's pose from camera 0 back
    assert np.allclose(T21 @ T10, T_C2_C0, atol=1e-12)
    assert data["cam2"]["rostopic"] == "/cam2/image_raw"
    with pytest.raises(InputError, match="one transform per camera"):
        write_kalibr_rig_camchain([CAMERA, CAMERA], [T_C1_C0, T_C2_C0, T_C2_C0], path)
