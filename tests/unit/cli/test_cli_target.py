"""``--target FILE`` (a Kalibr target YAML) on the commands that take a board, and ``cvsflow init``
recognising a Kalibr target file in a recording folder."""

import cv2
import numpy as np
import pytest
import yaml

from cvsflow import cli
from tests.helpers.real_data import REAL_DATA, need_real_file

YAC_TARGET = "yac-mocap-aprilgrid/calib_mocap-intel_d435i.yaml"


def test_calibrate_yac_frames_from_their_target_file(tmp_path, capsys):
    """`cvsflow calibrate FRAMES --target yac.yaml`: the AprilGrid's intrinsics, its board and
    the detector recorded in camera.yaml."""
    target = need_real_file(YAC_TARGET)
    frames = REAL_DATA / "yac-mocap-aprilgrid" / "cam0" / "data"
    assert cli.main(["calibrate", str(frames), "--target", str(target), "--out", str(tmp_path)]) == 0
    cam = yaml.safe_load((tmp_path / "camera.yaml").read_text())
    assert cam["board"]["type"] == "aprilgrid" and cam["n_used"] == 30
    assert cam["K"][0][0] == pytest.approx(606.07, abs=3.0) and "apriltag3" in cam["detector"]
    assert "fx 60" in capsys.readouterr().out
    assert "Kalibr AprilGrid of 6x6 tags" in (tmp_path / "camchain.yaml").read_text()


@pytest.mark.skipif(not (REAL_DATA / "opencv-chessboard").is_dir(), reason="OpenCV sample stills absent")
def test_checkerboard_target_equals_inner(tmp_path):
    """A Kalibr checkerboard file (targetCols 9 x targetRows 6 inner corners) calibrates exactly as
    --inner 9x6 --square-m 0.025."""
    path = tmp_path / "checker.yaml"
    path.write_text("target_type: checkerboard\ntargetCols: 9\ntargetRows: 6\n"
                    "rowSpacingMeters: 0.025\ncolSpacingMeters: 0.025\n")
    stills = str(REAL_DATA / "opencv-chessboard")
    assert cli.main(["calibrate", stills, "--target", str(path), "--out", str(tmp_path / "a")]) == 0
    assert cli.main(["calibrate", stills, "--inner", "9x6", "--square-m", "0.025", "--out", str(tmp_path / "b")]) == 0
    a, b = (yaml.safe_load((tmp_path / d / "camera.yaml").read_text()) for d in ("a", "b"))
    assert a == b


def test_board_option_errors_are_one_line(tmp_path, capsys):
    """--target with --square-m, --inner without --square-m, --target and --inner together, an
    unsupported target type, and handeye without a board: each a one-line error, nothing written."""
    path = tmp_path / "t.yaml"
    path.write_text("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\ntagSpacing: 0.3\n")
    circles = tmp_path / "c.yaml"
    circles.write_text("target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\nspacingMeters: 0.02\n")
    still = tmp_path / "stills" / "a.png"
    still.parent.mkdir()
    cv2.imwrite(str(still), np.zeros((48, 64), np.uint8))
    out = str(tmp_path / "out")
    cases = [
        (["calibrate", str(still.parent), "--target", str(path), "--square-m", "0.02", "--out", out],
         "leave out --square-m"),
        (["calibrate", str(still.parent), "--inner", "9x6", "--out", out], "--square-m"),
        (["calibrate", str(still.parent), "--target", str(circles), "--out", out], "circlegrid"),
        (["handeye", "--stills", str(still.parent), "--poses", "p.yaml", "--camera", "c.yaml", "--out", out],
         "the board: give --inner NXxNY with --square-m, or --target FILE"),
        (["calibrate-rig", "a", "b", "--target", str(tmp_path / "none.yaml"), "--out", out], "file not found"),
    ]
    for argv, match in cases:
        assert cli.main(argv) == 1, argv
        err = capsys.readouterr().err
        assert err.startswith("cvsflow: error:") and match in err and err.count("\n") == 1, err
    with pytest.raises(SystemExit) as exc:
        cli.main(["calibrate", str(still.parent), "--inner", "9x6", "--target", str(path), "--out", out])
    assert exc.value.code == 2
    assert not (tmp_path / "out").exists()


def test_init_takes_a_kalibr_target_file(tmp_path):
    """A recording folder with a Kalibr target file: the session names it as target, no board
    and no chessboard search; a circle-grid file is noted as unusable."""
    rec = tmp_path / "rec"
    (rec / "frames").mkdir(parents=True)
    for i in range(3):
        cv2.imwrite(str(rec / "frames" / f"{i}.png"), np.full((48, 64), 200, np.uint8))
    (rec / "april.yaml").write_text("target_type: aprilgrid\ntagCols: 6\ntagRows: 6\ntagSize: 0.088\n"
                                    "tagSpacing: 0.3\n")
    (rec / "a_circles.yaml").write_text("target_type: circlegrid\ntargetCols: 6\ntargetRows: 7\n")
    (rec / "other.yaml").write_text("anything: 1\n")
    out = tmp_path / "session.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "lab"]) == 0
    text = out.read_text()
    session = yaml.safe_load(text)["sessions"]["lab"]
    assert session["target"] == str(rec / "april.yaml") and "board" not in session
    assert "AprilGrid of 6x6 tags" in text and "a_circles.yaml: a target file cvsflow cannot use" in text
