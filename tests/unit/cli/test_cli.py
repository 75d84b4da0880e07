"""The `cvsflow` command: real stills, exports, init, run, exit codes and one-line errors."""

import copy
import re
from pathlib import Path

import cv2
import numpy as np
import pandas as pd
import pytest
import yaml

from cvsflow import cli
from cvsflow.geometry.transforms import R_from_euler, invert_T, make_T
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.synth.stereo import render_shared_stills

REAL = Path("/work/shared/data/real/opencv-chessboard")

CAMERA = {
    "K": [[702.1, 0.0, 331.4], [0.0, 698.3, 247.2], [0.0, 0.0, 1.0]],
    "dist": [-0.12, 0.09, 0.0009, -0.0007, -0.002],
    "width": 640,
    "height": 480,
    "rms_px": 0.21,
    "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
}


def test_help_lists_every_subcommand(capsys):
    with pytest.raises(SystemExit) as exc:
        cli.main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out.lower()
    for name in ("calibrate", "export", "run", "init", "inner corners", "exit codes"):
        assert name in out


@pytest.mark.skipif(not REAL.is_dir(), reason="OpenCV sample stills not on this machine")
def test_calibrate_real_opencv_stills(tmp_path, capsys):
    """--subpix-window-px 11 --no-outlier-rejection is OpenCV's sample: its published result,
    exactly; left02, whose near squares the 11 px window overreaches, is named."""
    rc = cli.main(["calibrate", str(REAL), "--inner", "9x6", "--square-m", "0.025", "--out", str(tmp_path),
                   "--subpix-window-px", "11", "--no-outlier-rejection"])
    assert rc == 0
    cam = yaml.safe_load((tmp_path / "camera.yaml").read_text())
    K = np.asarray(cam["K"])
    np.testing.assert_allclose(
        [K[0, 0], K[1, 1], K[0, 2], K[1, 2]], [536.07345, 536.01636, 342.37047, 235.53687], atol=1e-3
    )
    assert cam["rms_px"] == pytest.approx(0.408695, abs=1e-5)
    fs = cv2.FileStorage(str(tmp_path / "camera_opencv.yaml"), cv2.FILE_STORAGE_READ)
    np.testing.assert_allclose(fs.getNode("camera_matrix").mat(), K)
    fs.release()
    assert (tmp_path / "camchain.yaml").is_file() and (tmp_path / "camera_info.yaml").is_file()
    assert [s["name"] for s in cam["outliers"]["named_stills"]] == ["left02.jpg"]
    assert "stills named: left02.jpg" in capsys.readouterr().out


@pytest.mark.skipif(not REAL.is_dir(), reason="OpenCV sample stills not on this machine")
def test_calibrate_real_opencv_stills_default_and_models(tmp_path, capsys):
    """The default lands on the three-route consensus (fx 533.2-533.9, cy 233.8-233.9) with
    the summary line, verdicts, the uncertainty map and every export; the rational model's
    Kalibr file is refused with its reason, the fisheye's mrcal file too."""
    rc = cli.main(["calibrate", str(REAL), "--inner", "9x6", "--square-m", "0.025", "--out",
                   str(tmp_path / "default")])
    assert rc == 0
    cam = yaml.safe_load((tmp_path / "default" / "camera.yaml").read_text())
    K = np.asarray(cam["K"])
    assert abs(K[0, 0] - 533.55) < 1.4 and abs(K[1, 2] - 233.85) < 1.1
    out = capsys.readouterr().out
    assert "0 of 702 corners left out" in out and "projection uncertainty at infinity" in out
    assert "quality: coverage WARN" in out and "cross_validation ok" in out
    for name in ("projection_uncertainty.png", "camera.cameramodel", "camchain.yaml"):
        assert (tmp_path / "default" / name).is_file()
    assert "LENSMODEL_OPENCV5" in (tmp_path / "default" / "camera.cameramodel").read_text()
    for model, refused, missing in (("opencv8", "as kalibr", "camchain.yaml"),
                                    ("fisheye4", "as mrcal", "camera.cameramodel")):
        assert cli.main(["calibrate", str(REAL), "--inner", "9x6", "--square-m", "0.025", "--out",
                         str(tmp_path / model), "--model", model]) == 0
        out = capsys.readouterr().out
        assert f"({model})" in out and refused in out
        assert not (tmp_path / model / missing).exists()
        assert yaml.safe_load((tmp_path / model / "camera.yaml").read_text())["model"] == model


@pytest.mark.parametrize("argv, mine", [
    (["calibrate", "STILLS", "--inner", "9x6", "--square-m", "0.025", "--out", "OUT"], "camera.yaml"),
    (["calibrate", "STILLS", "--inner", "9x6", "--square-m", "0.025", "--out", "OUT"], "camchain.yaml"),
    (["calibrate-rig", "STILLS", "STILLS", "--inner", "9x6", "--square-m", "0.025", "--out", "OUT"],
     "cam1/camera_info.yaml"),
    (["export", "camera", "SRC", "--format", "ros", "--out", "OUT/ci.yaml"], "ci.yaml"),
    (["export", "trajectory", "SRC", "--out-dir", "OUT"], "vicon_T_C_B.tum"),
    (["handeye", "--stills", "STILLS", "--poses", "p.yaml", "--inner", "9x6", "--square-m", "0.025",
      "--camera", "cam.xml", "--out", "OUT"], "handeye.yaml"),
], ids=["calibrate", "calibrate-formats", "calibrate-rig", "export-camera", "export-trajectory", "handeye"])
def test_out_over_a_users_file_is_refused_without_force(tmp_path, capsys, argv, mine):
    """--out into a folder holding a user's file of a name the command writes: before, replaced
    in silence; now exit 1, one line naming the file and --force, before anything is read or
    computed, the file untouched and nothing else written."""
    out = tmp_path / "out"
    (out / mine).parent.mkdir(parents=True)
    (out / mine).write_text("the user's own\n")
    subs = {"OUT": str(out), "STILLS": str(tmp_path / "none"), "SRC": str(tmp_path / "none")}
    args = [subs.get(a, a.replace("OUT", str(out))) for a in argv]
    assert cli.main(args) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and f"{out / mine} exists" in err and "--force" in err
    assert (out / mine).read_text() == "the user's own\n"
    assert sorted(p for p in out.rglob("*") if p.is_file()) == [out / mine]


def test_force_replaces_the_files_of_the_same_names(tmp_path, capsys):
    """With --force the command replaces its own files' names in OUT (export camera)."""
    write_yaml(CAMERA, tmp_path / "camera.yaml")
    (tmp_path / "ci.yaml").write_text("old\n")
    argv = ["export", "camera", str(tmp_path), "--format", "ros", "--out", str(tmp_path / "ci.yaml")]
    assert cli.main(argv) == 1
    assert cli.main([*argv, "--force"]) == 0
    assert yaml.safe_load((tmp_path / "ci.yaml").read_text())["image_width"] == 640


def test_export_camera_and_missing_file_is_one_line(tmp_path, capsys):
    write_yaml(CAMERA, tmp_path / "camera.yaml")
    assert cli.main(["export", "camera", str(tmp_path), "--format", "ros", "--out", str(tmp_path / "ci.yaml")]) == 0
    data = yaml.safe_load((tmp_path / "ci.yaml").read_text())
    np.testing.assert_allclose(data["distortion_coefficients"]["data"], CAMERA["dist"])
    rc = cli.main(["export", "camera", str(tmp_path / "nope"), "--format", "kalibr", "--out", str(tmp_path / "k")])
    err = capsys.readouterr().err
    assert rc == 1
    assert err.count("\n") == 1 and "nope" in err and "Traceback" not in err


def _pairs_from_truth(n=40, seed=0):
    """pairs.parquet columns from known mountings: T_Cm_Bm = T_Cm_C T_C_B T_Bm_B^-1."""
    import pandas as pd

    from cvsflow.geometry.transforms import T_from_pose6, invert_T, quat_from_R, rvec_tvec_from_T

    rng = np.random.default_rng(seed)
    T_Cm_C = T_from_pose6([0.03, -0.02, 0.05, -1.5708, 0.0, -1.5708])
    T_Bm_B = T_from_pose6([0.2, 0.395, -0.004, np.pi, 0.0, 0.0])
    T_C_B = T_from_pose6(np.column_stack([rng.normal(scale=0.3, size=(n, 2)), rng.uniform(1, 3, n),
                                          rng.normal(scale=0.3, size=(n, 3))]))
    T_Cm_Bm = T_Cm_C @ T_C_B @ invert_T(T_Bm_B)
    t_s = np.arange(n) / 30.0
    t_s[n // 2:] += 1.0  # a gap: TUM keeps the true times
    pairs = pd.DataFrame({"frame": np.arange(n), "t_s": t_s})
    rt = [rvec_tvec_from_T(T) for T in T_C_B]
    for i in range(3):
        pairs[f"cvs_rvec_{i}"] = [r[0].ravel()[i] for r in rt]
    for k, a in enumerate("xyz"):
        pairs[f"cvs_{a}_m"] = T_C_B[:, k, 3]
        pairs[f"cmbm_{a}_m"] = T_Cm_Bm[:, k, 3]
    q = quat_from_R(T_Cm_Bm[:, :3, :3])
    for k, a in enumerate("xyzw"):
        pairs[f"cmbm_q{a}"] = q[:, k]
    return pairs, T_C_B, T_Cm_Bm, {"T_Cm_C": T_Cm_C.tolist(), "T_Bm_B": T_Bm_B.tolist()}


def _read_tum(path):
    """As evo's TUM reader does: '#' comments, 8 columns (t, tx, ty, tz, qx, qy, qz, qw)."""
    a = np.loadtxt(path, comments="#")
    assert a.ndim == 2 and a.shape[1] == 8
    return a


def test_export_trajectory_writes_unaligned_tum_and_the_vicon_in_cvs_frames(tmp_path, capsys):
    from cvsflow.geometry.transforms import R_from_quat

    pairs, T_C_B, T_Cm_Bm, se3 = _pairs_from_truth()
    write_parquet(pairs, tmp_path / "pairs.parquet")
    write_yaml(se3, tmp_path / "se3" / "calib" / "result.yaml")
    assert cli.main(["export", "trajectory", str(tmp_path), "--out-dir", str(tmp_path / "t")]) == 0
    assert "evo_ape tum" in capsys.readouterr().out
    cvs = _read_tum(tmp_path / "t" / "cvs_T_C_B.tum")
    vic_raw = _read_tum(tmp_path / "t" / "vicon_T_Cm_Bm.tum")
    vic = _read_tum(tmp_path / "t" / "vicon_T_C_B.tum")
    np.testing.assert_allclose(cvs[:, 0], pairs["t_s"], atol=1e-9)  # video clock, gap kept
    np.testing.assert_allclose(cvs[:, 1:4], T_C_B[:, :3, 3], atol=1e-8)
    np.testing.assert_allclose(R_from_quat(cvs[:, 4:]), T_C_B[:, :3, :3], atol=1e-7)
    np.testing.assert_allclose(vic_raw[:, 1:4], T_Cm_Bm[:, :3, 3], atol=1e-8)
    # Unaligned but in the same frames: the Vicon through the mountings is the CVS pose itself.
    np.testing.assert_allclose(vic[:, 1:4], cvs[:, 1:4], atol=1e-7)
    np.testing.assert_allclose(R_from_quat(vic[:, 4:]), R_from_quat(cvs[:, 4:]), atol=1e-7)
    # ... while the marker-body trajectory is far from it (the mountings are not removed).
    assert np.abs(vic_raw[:, 1:4] - cvs[:, 1:4]).max() > 0.1


def test_export_trajectory_without_se3_and_bad_tables(tmp_path, capsys):
    pairs, *_ = _pairs_from_truth(10)
    write_parquet(pairs, tmp_path / "pairs.parquet")
    assert cli.main(["export", "trajectory", str(tmp_path), "--out-dir", str(tmp_path / "t")]) == 0
    assert "vicon_T_C_B (the Vicon in the CVS frames) not written" in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / "t").iterdir()) == ["cvs_T_C_B.tum", "vicon_T_Cm_Bm.tum"]
    rc = cli.main(["export", "trajectory", str(tmp_path), "--out-dir", str(tmp_path / "u"),
                   "--se3", str(tmp_path / "none.yaml")])
    assert rc == 1 and "none.yaml" in capsys.readouterr().err
    write_parquet(pairs.drop(columns=["cmbm_qw"]), tmp_path / "bad.parquet")
    rc = cli.main(["export", "trajectory", str(tmp_path / "bad.parquet"), "--out-dir", str(tmp_path / "v")])
    err = capsys.readouterr().err
    assert rc == 1 and "cmbm_qw" in err and "bad.parquet" in err and not (tmp_path / "v").exists()


def test_init_finds_recording_and_never_overwrites(tmp_path, capsys):
    from cvsflow.io.mocap.markers import marker_table
    from cvsflow.io.mocap.vicon import write_nexus_csv
    from tests.helpers.board_images import board_centre_pose, render_board

    K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])
    rec = tmp_path / "rec"
    (rec / "stills").mkdir(parents=True)
    for i in range(3):
        gray, _ = render_board(board_centre_pose([0.1 * i, -0.1, 0.0], [0.0, 0.0, 1.2]), K, seed=i)
        cv2.imwrite(str(rec / "stills" / f"s{i}.png"), gray)
    (rec / "take.mp4").write_bytes(b"")
    names = ["cam:C1", "cam:C2", "board:B1"]
    xyz = np.random.default_rng(1).normal(size=(4, 3, 3))
    write_nexus_csv(marker_table(np.arange(4), xyz, names, 100.0), rec / "take.csv", 100.0)
    out = tmp_path / "session.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "s1"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["s1"]
    assert cfg["calib_dir"].endswith("stills") and cfg["video"].endswith("take.mp4")
    assert cfg["mocap"]["file"].endswith("take.csv")
    assert cfg["board"]["squares_x"] == 6 and cfg["board"]["squares_y"] == 5  # 5x4 inner corners
    assert cfg["markers"]["camera"]["names"] == ["cam:C1", "cam:C2"]
    assert cfg["markers"]["board"]["names"] == ["board:B1"]
    assert "layout_m" not in cfg["markers"]["camera"]  # learned from the take unless measured
    text = out.read_text()
    assert f"# Use: cvsflow run {out} " in text and "a rigid body needs at least 3" in text
    before = out.read_text()
    assert cli.main(["init", str(rec), "--out", str(out)]) == 1
    assert out.read_text() == before
    assert "never overwrites" in capsys.readouterr().err


def test_init_leaves_out_an_empty_or_cut_still(tmp_path, caplog):
    """cvsflow init tries its board sizes on the first stills: an empty and a cut one among them
    are left out with a WARNING naming them (an empty one stopped init), as the calibration
    leaves them out; the board comes from the others."""
    from tests.helpers.board_images import board_centre_pose, render_board

    K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])
    rec = tmp_path / "rec"
    (rec / "stills").mkdir(parents=True)
    for i in range(4):
        gray, _ = render_board(board_centre_pose([0.1 * i, -0.1, 0.0], [0.0, 0.0, 1.2]), K, seed=i)
        cv2.imwrite(str(rec / "stills" / f"s{i}.jpg"), gray)
    (rec / "stills" / "a_empty.jpg").write_bytes(b"")
    data = (rec / "stills" / "s0.jpg").read_bytes()
    (rec / "stills" / "s0.jpg").write_bytes(data[: len(data) // 2])
    out = tmp_path / "session.yaml"
    with caplog.at_level("WARNING"):
        assert cli.main(["init", str(rec), "--out", str(out), "--name", "s1"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["s1"]
    assert cfg["board"]["squares_x"] == 6 and cfg["board"]["squares_y"] == 5
    assert "a_empty.jpg: empty file (0 bytes)" in caplog.text
    assert "s0.jpg: cannot be decoded (truncated?" in caplog.text


def test_init_on_a_6dof_only_qtm_export_uses_the_system_bodies(tmp_path):
    """A QTM 6D TSV (no markers): init names the format, sets bodies_from: system and guesses each
    body's system_body from the export's body names; the config validates with the demo config."""
    from cvsflow.geometry.transforms import make_T
    from cvsflow.io.mocap.qualisys import write_qtm_tsv
    from cvsflow.mocap.bodies import bodies_from_poses

    rec = tmp_path / "rec"
    rec.mkdir()
    n = 20
    T = np.broadcast_to(make_T(np.eye(3), [0.1, 0.2, 0.3]), (n, 4, 4))
    bodies = pd.concat([bodies_from_poses(np.arange(n), np.arange(n) / 100.0, b, T, np.full(n, 1e-4),
                                          np.full(n, -1)) for b in ("webcam rig", "chessboard")],
                       ignore_index=True)
    bodies.attrs["rate_hz"] = 100.0
    write_qtm_tsv(rec / "take_6D.tsv", bodies=bodies, layout="old")
    out = tmp_path / "s.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "q"]) == 0
    cfg = yaml.safe_load(out.read_text())["sessions"]["q"]
    assert cfg["mocap"]["file"].endswith("take_6D.tsv")
    assert cfg["mocap"] == {"file": cfg["mocap"]["file"], "format": "qtm_tsv", "bodies_from": "system"}
    assert cfg["markers"] == {"camera": {"system_body": "webcam rig"}, "board": {"system_body": "chessboard"}}
    # with the user's TODOs filled, the session passes the schema and the session checks
    import copy

    from snakemake.utils import update_config, validate

    from cvsflow.io.mocap.formats import mocap_settings

    root = Path(__file__).resolve().parents[3]
    cfg.update(calib_dir=str(rec), video=str(rec / "take.mp4"))
    cfg["board"] = {"squares_x": 6, "squares_y": 5, "square_m": 0.03}
    config = yaml.safe_load((root / "config" / "config.yaml").read_text())
    update_config(config, copy.deepcopy({"sessions": {"q": cfg}}))
    validate(config, str(root / "cvsflow" / "workflow" / "schemas" / "config.schema.yaml"))
    assert mocap_settings("q", config["sessions"]["q"])["bodies_from"] == "system"


def test_bad_inner_is_usage_error():
    with pytest.raises(SystemExit) as exc:
        cli.main(["calibrate", "d", "--inner", "9by6", "--square-m", "0.02", "--out", "o"])
    assert exc.value.code == 2


def test_init_names_a_session_as_a_wildcard_and_reports_what_is_missing(tmp_path, capsys):
    rec = tmp_path / "lab 1 (May)"
    rec.mkdir()
    assert cli.main(["init", str(rec), "--out", str(tmp_path / "s.yaml")]) == 0
    cfg = yaml.safe_load((tmp_path / "s.yaml").read_text())
    (name, session), = cfg["sessions"].items()
    assert name == "lab_1__May_"
    assert session["calib_dir"] == session["video"] == session["mocap"]["file"] == "TODO"
    out = capsys.readouterr().out
    assert "set calib_dir" in out and "set video" in out and "set mocap.file" in out


def _readme_session_block():
    """The YAML block of the README's 'Your own recording' section."""
    readme = (Path(__file__).resolve().parents[3] / "README.md").read_text()
    section = readme.split("## Your own recording", 1)[1]
    return yaml.safe_load(section.split("```yaml", 1)[1].split("```", 1)[0])


def test_readme_session_config_validates_on_its_own():
    """The README's copyable session, alone (as `cvsflow run` reads it: no demo merged in),
    passes the schema, which fills every block it leaves out with the documented defaults, and
    runs every stage."""
    from snakemake.utils import validate

    from cvsflow.workflow.config import SCHEMA
    from cvsflow.workflow.sessions import check_sessions

    config = _readme_session_block()
    assert set(config) == {"sessions"}
    validate(config, str(SCHEMA))
    assert set(config["sessions"]) == {"lab1"} and config["flights"] == {}
    stages = check_sessions(config["sessions"])
    assert {"calibrate", "poses", "mocap", "pairs"} <= set(stages["lab1"])
    lab1 = config["sessions"]["lab1"]
    assert lab1["board"]["squares_x"] == 6 and len(lab1["markers"]["camera"]["layout_m"]) == 4
    # blocks left out entirely are filled to their last key
    assert config["pnp"]["ransac_reproj_px"] == 3.0 and config["sync"]["method"] == "angular_speed"
    assert config["evaluate"]["n_folds"] == 5 and config["optimise"]["se3"]["loss"] == "soft_l1"
    assert config["mocap"]["filter"]["enabled"] is False and config["corners"]["subpix_window_px"] == 5


def test_calibrate_rig_from_rendered_stereo_stills(tmp_path, capsys):
    cfg0 = yaml.safe_load((Path(__file__).resolve().parents[3] / "config" / "config.yaml").read_text())
    cfg0 = cfg0["sessions"]["demo"]
    cfg1 = copy.deepcopy(cfg0)
    cfg1["synth"]["camera"].update(fx_px=760.0, fy_px=757.0, cx_px=318.0, cy_px=236.0)
    T_C1_C0 = invert_T(make_T(R_from_euler([0.0, -0.2, 0.0]), [0.6, 0.0, 0.0]))
    stills, _ = render_shared_stills([cfg0, cfg1], [np.eye(4), T_C1_C0], 12, seed=3)
    for c, cam_stills in enumerate(stills):
        (tmp_path / f"cam{c}").mkdir()
        for name, img in cam_stills:
            cv2.imwrite(str(tmp_path / f"cam{c}" / name), img)
    out = tmp_path / "rig"
    assert cli.main(["calibrate-rig", str(tmp_path / "cam0"), str(tmp_path / "cam1"), "--inner", "5x4",
                     "--square-m", "0.09", "--out", str(out)]) == 0
    printed = re.search(r"baseline ([0-9.]+) \+- ([0-9.]+) mm", capsys.readouterr().out)
    assert printed and abs(float(printed[1]) - 0.6) < 4e-3 * float(printed[2])
    rig = yaml.safe_load((out / "rig.yaml").read_text())
    cam1 = rig["cameras"][1]
    assert abs(cam1["baseline_m"] - 0.6) < 4 * cam1["baseline_std_m"] < 0.01
    assert np.allclose(np.array(cam1["T_Ci_C0"])[:3, 3], T_C1_C0[:3, 3], atol=0.01)
    chain = yaml.safe_load((out / "camchain.yaml").read_text())
    assert np.allclose(chain["cam1"]["T_cn_cnm1"], cam1["T_Ci_C0"])
    assert (out / "cam1" / "camera.yaml").is_file() and (out / "cam0" / "calib_corners.parquet").is_file()
    # one folder is not a rig: one line on stderr, exit 1
    assert cli.main(["calibrate-rig", str(tmp_path / "cam0"), "--inner", "5x4", "--square-m", "0.09",
                     "--out", str(out)]) == 1
    assert "two or more" in capsys.readouterr().err
