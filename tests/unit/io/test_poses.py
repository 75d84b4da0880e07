"""Pose-list readers (ViSP vpPoseVector, TUM, declared CSV) and known-intrinsics readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cvsflow.exceptions import InputError
from cvsflow.geometry import transforms as tf
from cvsflow.handeye.stills import pair_stills_with_poses
from cvsflow.io.camera_formats import write_opencv_yaml
from cvsflow.io.files import write_yaml
from cvsflow.io.poses import (
    T_from_pose_vector,
    pose_table_T,
    read_csv_poses,
    read_pose_list,
    read_tum_poses,
    read_visp_pose_vector,
)
from cvsflow.io.visp import read_known_camera, read_visp_camera


def _real() -> Path:
    from tests.helpers.real_data import REAL_DATA

    root = REAL_DATA
    if not root.is_dir():
        pytest.skip(f"real data not found at {root}")
    return root


# ------------------------------------------------------------------------------ ViSP poses


def test_visp_pose_vectors_of_the_franka_set():
    """The 8 Franka poses: values as in franka_pose_rPe_1.yaml, theta-u as a rotation vector."""
    d = _real() / "visp" / "eye-in-hand"
    table = read_pose_list(d / "franka_pose_rPe_*.yaml", "visp")
    assert list(table["name"]) == [f"franka_pose_rPe_{i}" for i in range(1, 9)]
    T = pose_table_T(table)
    # franka_pose_rPe_1.yaml: [0.335091, -0.0321497, 0.30857, -3.01226, 0.0236777, -0.451343]
    np.testing.assert_allclose(T[0, :3, 3], [0.335091, -0.0321497, 0.30857])
    w = tf.rvec_from_R(T[0, :3, :3])
    tu = np.array([-3.01226, 0.0236777, -0.451343])
    # theta = |tu| = 3.046 rad is near pi: the rotation vector may come back as the other one
    assert np.allclose(w, tu, atol=1e-9) or np.allclose(
        w, tu / np.linalg.norm(tu) * (np.linalg.norm(tu) - 2 * np.pi), atol=1e-9
    )
    np.testing.assert_allclose(T_from_pose_vector(read_visp_pose_vector(d / "franka_pose_rPe_2.yaml"))[0],
                               T[1], atol=1e-12)  # fmt: skip
    assert table["origin"].iloc[2].endswith("franka_pose_rPe_3.yaml")


def test_visp_pose_list_of_n_rows(tmp_path):
    """rows: N, cols: 6 holds N poses, in order."""
    p = tmp_path / "poses.yaml"
    p.write_text("rows: 2\ncols: 6\ndata:\n  - [0.1, 0.2, 0.3, 0, 0, 0.5]\n  - [1, 2, 3, 0.1, 0, 0]\n")
    pose6 = read_visp_pose_vector(p)
    np.testing.assert_allclose(pose6, [[0.1, 0.2, 0.3, 0, 0, 0.5], [1, 2, 3, 0.1, 0, 0]])
    T = T_from_pose_vector(pose6)
    np.testing.assert_allclose(tf.rotation_angle(T[0, :3, :3]), 0.5)


@pytest.mark.parametrize(
    "text, match",
    [
        ("rows: 6\ncols: 1\ndata:\n  - [0.1]\n  - [0.2]\n  - [abc]\n  - [0]\n  - [0]\n  - [0]\n",
         r"line 6: 'abc' is not a number"),
        ("rows: 6\ncols: 1\ndata:\n  - [0.1]\n  - [0.2]\n", r"line 4: data has 2 rows; expected 6"),
        ("rows: 3\ncols: 3\ndata: []\n", "expected a vpPoseVector"),
        ("cols: 1\ndata: []\n", "key 'rows' missing"),
        ("rows: 6\ncols: 1\ndata:\n  - [0.1, 2]\n  - [0]\n  - [0]\n  - [0]\n  - [0]\n  - [0]\n",
         "line 4: row has 2 values"),
    ],
)  # fmt: skip
def test_visp_pose_bad_cells_name_file_and_line(tmp_path, text, match):
    """A bad vpPoseVector names the file and the line of the bad cell."""
    p = tmp_path / "pose.yaml"
    p.write_text(text)
    with pytest.raises(InputError, match=match) as exc:
        read_visp_pose_vector(p)
    assert str(p) in str(exc.value)


# ------------------------------------------------------------------------------ TUM


def test_tum_poses_of_fr2_desk_in_file_order():
    """fr2_desk_groundtruth.txt: 20957 poses, the first (line 4) as written, file order kept."""
    path = _real() / "tum-fr2-desk" / "fr2_desk_groundtruth.txt"
    table = read_tum_poses(path)
    assert len(table) == 20957
    assert table["origin"].iloc[0] == f"{path}, line 4"
    # line 4: 1311868163.8697 -0.1357 -1.4217 1.4764 0.6453 -0.5498 0.3363 -0.4101
    assert table["t_s"].iloc[0] == pytest.approx(1311868163.8697)
    np.testing.assert_allclose(table[["x_m", "y_m", "z_m"]].iloc[0], [-0.1357, -1.4217, 1.4764])
    q = np.array([0.6453, -0.5498, 0.3363, -0.4101])
    np.testing.assert_allclose(pose_table_T(table)[0, :3, :3], tf.R_from_quat(q / np.linalg.norm(q)),
                               atol=1e-12)  # fmt: skip
    assert table["t_s"].iloc[-1] == pytest.approx(1311868263.2342)


def test_tum_file_order_is_kept_when_times_go_back(tmp_path):
    """A pose list is paired by position, so rows stay in file order even if times decrease."""
    p = tmp_path / "p.txt"
    p.write_text("# t x y z qx qy qz qw\n5 1 0 0 0 0 0 1\n\n2 2 0 0 0 0 0 1\n")
    table = read_tum_poses(p)
    assert list(table["x_m"]) == [1.0, 2.0]
    assert list(table["origin"]) == [f"{p}, line 2", f"{p}, line 4"]


def test_tum_bad_line_named(tmp_path):
    """A TUM line with a bad number names the file and line."""
    p = tmp_path / "p.txt"
    p.write_text("1 0 0 0 0 0 0 1\n2 0 x 0 0 0 0 1\n")
    with pytest.raises(InputError, match=r"line 2: not a number"):
        read_tum_poses(p)


# ------------------------------------------------------------------------------ CSV


def test_csv_euler_degrees_millimetres_and_names(tmp_path):
    """Declared columns: mm and Euler roll-pitch-yaw in degrees (R = Rz Ry Rx); name column kept."""
    p = tmp_path / "robot.csv"
    p.write_text("image,t,X,Y,Z,roll,pitch,yaw\nimg-1.png,0.5,100,200,300,10,20,30\n"
                 "img-2.png,0.1,-5,0,1,0,0,90\n")  # fmt: skip
    spec = {"time_col": "t", "pos_cols": ["X", "Y", "Z"], "pos_unit": "mm", "rot": "euler_rpy",
            "rot_cols": ["roll", "pitch", "yaw"], "angle_unit": "deg", "name_col": "image"}  # fmt: skip
    table = read_csv_poses(p, spec)
    assert list(table["name"]) == ["img-1.png", "img-2.png"]  # file order, not time order
    T = pose_table_T(table)
    np.testing.assert_allclose(T[0, :3, 3], [0.1, 0.2, 0.3])
    np.testing.assert_allclose(T[0, :3, :3], tf.R_from_euler(np.radians([10, 20, 30])), atol=1e-12)
    np.testing.assert_allclose(T[1, :3, :3] @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    assert table["origin"].iloc[1] == f"{p}, line 3"


def test_csv_bad_cell_named(tmp_path):
    """A CSV cell that is not a number names the file, row (= line) and column."""
    p = tmp_path / "robot.csv"
    p.write_text("t,x,y,z,qx,qy,qz,qw\n0,0,0,0,0,0,0,1\n1,0,zero,0,0,0,0,1\n")
    with pytest.raises(InputError, match=r"row 3, column y: 'zero' is not a number"):
        read_pose_list(p, "csv", {})


def test_pose_list_errors(tmp_path):
    """No file matching, unknown format, csv without a spec: named errors."""
    with pytest.raises(InputError, match="no pose file matches"):
        read_pose_list(tmp_path / "none_*.yaml", "visp")
    (tmp_path / "a.txt").write_text("1 0 0 0 0 0 0 1\n")
    with pytest.raises(InputError, match="expected one of"):
        read_pose_list(tmp_path / "a.txt", "kuka")
    with pytest.raises(InputError, match="needs a spec"):
        read_pose_list(tmp_path / "a.txt", "csv")


# ------------------------------------------------------------------------------ pairing


def test_pairing_rules():
    """Stills pair with poses by name, then by the number in the names, then by position."""
    stills = ["franka_image-1.png", "franka_image-2.png", "franka_image-10.png"]
    idx, rule = pair_stills_with_poses(stills, ["rPe_10", "rPe_1", "rPe_2"])
    assert (idx, rule) == ([1, 2, 0], "by the number in the file names")
    idx, rule = pair_stills_with_poses(stills, ["franka_image-2", "franka_image-1.png",
                                                "franka_image-10"])  # fmt: skip
    assert (idx, rule) == ([1, 0, 2], "by name")
    assert pair_stills_with_poses(stills, ["", "", ""]) == ([0, 1, 2], "by position")
    assert pair_stills_with_poses(stills, ["rPe_1", "rPe_2"])[0] == [0, 1, -1]
    with pytest.raises(InputError, match="3 stills and 2 poses"):
        pair_stills_with_poses(stills, ["", ""])


# ------------------------------------------------------------------------------ cameras


def test_visp_camera_xml_of_the_franka_set():
    """franka_camera.xml: px, py, u0, v0 as in the file; kud = -0 becomes k1 = 0."""
    cam = read_known_camera(_real() / "visp" / "eye-in-hand" / "franka_camera.xml")
    np.testing.assert_allclose(cam["K"], [[607.5931396484375, 0, 323.46282958984375],
                                          [0, 607.574951171875, 243.25529479980469], [0, 0, 1]])  # fmt: skip
    assert cam["dist"] == [0.0] * 5 and (cam["width"], cam["height"]) == (640, 480)
    assert cam["model"] == "perspectiveProjWithDistortion" and cam["name"] == "Camera"


VISP_TWO_MODELS = """<?xml version="1.0"?>
<root>
  <camera>
    <name>Cam</name>
    <image_width>640</image_width>
    <image_height>480</image_height>
    <model>
      <type>perspectiveProjWithoutDistortion</type>
      <px>600</px>
      <py>601</py>
      <u0>320</u0>
      <v0>240</v0>
    </model>
    <model>
      <type>perspectiveProjWithDistortion</type>
      <px>602</px>
      <py>603</py>
      <u0>321</u0>
      <v0>{v0}</v0>
      <kud>-0.05</kud>
      <kdu>0.051</kdu>
    </model>
  </camera>
</root>
"""


def test_visp_camera_models(tmp_path):
    """With and without distortion chosen by name; auto takes the one with distortion (k1 = kud)."""
    p = tmp_path / "cam.xml"
    p.write_text(VISP_TWO_MODELS.format(v0=241))
    auto = read_visp_camera(p)
    assert auto["K"][0][0] == 602 and auto["dist"] == [-0.05, 0, 0, 0, 0] and auto["kdu"] == 0.051
    plain = read_visp_camera(p, model="perspectiveProjWithoutDistortion")
    assert plain["K"] == [[600, 0, 320], [0, 601, 240], [0, 0, 1]] and plain["dist"] == [0.0] * 5
    with pytest.raises(InputError, match="no camera matches"):
        read_visp_camera(p, name="Other")


def test_visp_camera_bad_cell_names_line(tmp_path):
    """A non-numeric intrinsic names the file, the line and the element."""
    p = tmp_path / "cam.xml"
    p.write_text(VISP_TWO_MODELS.format(v0="two-forty"))
    with pytest.raises(InputError, match=r"line 19, <v0>: 'two-forty' is not a number"):
        read_visp_camera(p)
    (tmp_path / "broken.xml").write_text("<root><camera>")
    with pytest.raises(InputError, match="not well-formed XML"):
        read_visp_camera(tmp_path / "broken.xml")


def test_known_camera_from_camera_yaml_and_opencv_storage(tmp_path):
    """camera.yaml and OpenCV FileStorage (written by cvsflow export) give the same K and dist."""
    cam = {"K": [[610.0, 0, 322.0], [0, 611.0, 244.0], [0, 0, 1]],
           "dist": [0.1, -0.2, 1e-3, -2e-3, 0.05], "width": 640, "height": 480,
           "std": {"fx": 0.5}}  # fmt: skip
    write_yaml(cam, tmp_path / "camera.yaml")
    write_opencv_yaml(cam, tmp_path / "camera_opencv.yaml")
    a = read_known_camera(tmp_path / "camera.yaml")
    b = read_known_camera(tmp_path / "camera_opencv.yaml")
    for c in (a, b):
        np.testing.assert_allclose(c["K"], cam["K"])
        np.testing.assert_allclose(c["dist"], cam["dist"])
        assert (c["width"], c["height"]) == (640, 480)
    assert a["std"] == {"fx": 0.5}
    (tmp_path / "bad.yaml").write_text("K: [[1, 0], [0, 1]]\ndist: [0]\nwidth: 1\nheight: 1\n")
    with pytest.raises(InputError, match="expected"):
        read_known_camera(tmp_path / "bad.yaml")


def test_opencv_storage_with_a_node_of_the_wrong_kind_names_file_and_node(tmp_path):
    """An OpenCV FileStorage camera file whose camera_matrix is a plain list (as hand-written
    files have it): before, a cv2.error traceback ('isMap()'); now an InputError naming the file,
    the node and what was expected. A missing image_width was read as 0 px; now it is named."""
    cam = {"K": [[610.0, 0, 322.0], [0, 611.0, 244.0], [0, 0, 1]],
           "dist": [0.1, -0.2, 1e-3, -2e-3, 0.05], "width": 640, "height": 480}  # fmt: skip
    path = tmp_path / "camera_opencv.yaml"
    write_opencv_yaml(cam, path)
    text = path.read_text()
    start = text.index("camera_matrix:")
    end = text.index("distortion_coefficients:")
    cases = {
        "camera_matrix: [610., 0., 322., 0., 611., 244., 0., 0., 1.]\n":
            r"node camera_matrix is a list \(a YAML sequence\); expected an !!opencv-matrix mapping",
        "camera_matrix: {fx: 610.}\n": r"node camera_matrix is a mapping without rows, cols, dt and data",
        "": r"no camera_matrix node; expected a 3x3 !!opencv-matrix",
    }
    for node, match in cases.items():
        path.write_text(text[:start] + node + text[end:])
        with pytest.raises(InputError, match=rf"{path}: {match}"):
            read_known_camera(path)
    path.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith("image_width")))
    with pytest.raises(InputError, match=rf"{path}: node image_width is missing; expected the image size"):
        read_known_camera(path)


def test_pose_format_detected_and_wrong_kind_named(tmp_path):
    """auto finds visp, tum and csv; a file read as the wrong kind says what it looks like."""
    from cvsflow.io.poses import sniff_pose_format

    visp = tmp_path / "p.yaml"
    visp.write_text("rows: 6\ncols: 1\ndata:\n" + "".join(f"  - [{v}]\n" for v in range(6)))
    tum = tmp_path / "p.txt"
    tum.write_text("# t x y z qx qy qz qw\n1 0 0 0 0 0 0 1\n2 1 0 0 0 0 0 1\n")
    csv = tmp_path / "p.csv"
    csv.write_text("name,t,x_mm,y_mm,z_mm,roll,pitch,yaw\nstill_1,0,0,0,0,0,0,1\n")
    assert [sniff_pose_format(p) for p in (visp, tum, csv)] == ["visp", "tum", "csv"]
    assert len(read_pose_list(tum, "auto")) == 2
    np.testing.assert_allclose(read_pose_list(visp, "auto")[["x_m", "y_m", "z_m"]].iloc[0], [0, 1, 2])
    with pytest.raises(InputError, match="looks like a visp pose list, not tum"):
        read_pose_list(visp, "tum")
    with pytest.raises(InputError, match="looks like a tum pose list, not visp"):
        read_pose_list(tum, "visp")
    nexus = tmp_path / "analogs.csv"
    nexus.write_text("Devices\n2000\n,,,\n")
    with pytest.raises(InputError, match="pose format not recognised"):
        read_pose_list(nexus, "auto")
