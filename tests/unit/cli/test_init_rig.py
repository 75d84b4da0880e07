"""`cvsflow init` on a rig recording: camera folders with stills, a video and shared views each.

The fake rig is built in tmp_path: rendered chessboard stills (tests/unit/board_images), a video
of a few frames (cv2.VideoWriter) per camera, and a Nexus CSV at the top.
"""

import copy
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from cvsflow import cli
from cvsflow.cli.init import build_session_config, camera_folders
from cvsflow.exceptions import InputError

REPO = Path(__file__).resolve().parents[3]
K = np.array([[600.0, 0, 320], [0, 600, 240], [0, 0, 1]])


def _stills(folder, names, seed=0, board=True):
    """Rendered stills of the demo board (5x4 inner corners), or grey ones with board=False
    (init's board guess costs about 2.6 s on a still showing none of the first sizes it tries)."""
    from tests.helpers.board_images import board_centre_pose, render_board

    folder.mkdir(parents=True)
    for i, name in enumerate(names):
        gray, _ = render_board(board_centre_pose([0.1 * i, -0.1, 0.0], [0.05 * i, 0.0, 1.2]), K,
                               seed=seed + i)
        cv2.imwrite(str(folder / name), gray if board else np.full_like(gray, 128))


def _video(path, n_frames=3):
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (160, 120), False)
    for i in range(n_frames):
        writer.write(np.full((120, 160), 40 * i, np.uint8))
    writer.release()
    assert path.stat().st_size > 0


def _mocap(path):
    from cvsflow.io.mocap.markers import marker_table
    from cvsflow.io.mocap.vicon import write_nexus_csv

    names = ["rig:R1", "rig:R2", "rig:R3", "board:B1", "board:B2", "board:B3"]
    xyz = np.random.default_rng(1).normal(size=(4, len(names), 3))
    write_nexus_csv(marker_table(np.arange(4), xyz, names, 100.0), path, 100.0)


SHARED = [f"shared_{i:03d}.png" for i in range(3)]


def make_rig(rec, cameras=("cam_left", "cam_right"), shared="camera", shared_names=None, board=True):
    """rec/<camera>/{calib/*.png, video.mp4} and the shared views (in rec/<camera>/shared/ or,
    with shared="top", rec/shared/<camera>/; None: no shared views); rec/take.csv."""
    for c, cam in enumerate(cameras):
        _stills(rec / cam / "calib", [f"c{i}.png" for i in range(3)], seed=10 * c, board=board)
        _video(rec / cam / "video.mp4")
        names = (shared_names or {}).get(cam, SHARED)
        if shared == "camera":
            _stills(rec / cam / "shared", names, seed=100 + 10 * c)
        elif shared == "top":
            _stills(rec / "shared" / cam, names, seed=100 + 10 * c)
    _mocap(rec / "take.csv")
    return rec


def assert_runnable_rig(name, session):
    """With square_m filled, the rig merged over config/config.yaml passes the schema and
    expand_rig_sessions; its per-camera sessions calibrate and track, the rig's runs the mocap stages."""
    from snakemake.utils import update_config, validate

    from cvsflow.workflow.sessions import check_sessions, expand_rig_sessions

    session = copy.deepcopy(session)
    session["board"]["square_m"] = 0.09
    config = yaml.safe_load((REPO / "config" / "config.yaml").read_text())
    update_config(config, {"sessions": {name: session}})
    validate(config, str(REPO / "cvsflow" / "workflow" / "schemas" / "config.schema.yaml"))
    plain, rigs = expand_rig_sessions(config["sessions"])
    cams = [c["name"] for c in session["cameras"]]
    assert rigs[name]["cameras"] == cams and not rigs[name]["synth"]
    assert rigs[name]["sessions"] == [f"{name}-{c}" for c in cams]
    stages = check_sessions(plain)
    assert stages[name] == ("mocap",)
    for c in cams:
        assert stages[f"{name}-{c}"] == ("calibrate", "poses")
    return plain, rigs


def test_init_writes_a_rig_session_from_camera_folders(tmp_path, capsys):
    rec = make_rig(tmp_path / "rec")
    out = tmp_path / "rig.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--name", "bar"]) == 0
    text = out.read_text()
    cfg = yaml.safe_load(text)["sessions"]["bar"]
    assert [c["name"] for c in cfg["cameras"]] == ["cam_left", "cam_right"]
    for c in cfg["cameras"]:
        assert c["calib_dir"] == str(rec / c["name"] / "calib")
        assert c["video"] == str(rec / c["name"] / "video.mp4")
        assert c["shared_dir"] == str(rec / c["name"] / "shared")
    assert "calib_dir" not in cfg and "video" not in cfg
    assert cfg["mocap"] == {"file": str(rec / "take.csv"), "format": "vicon_csv"}
    assert cfg["board"] == {"squares_x": 6, "squares_y": 5, "square_m": "TODO"}  # 5x4 inner corners
    assert cfg["markers"]["camera"]["names"] == ["rig:R1", "rig:R2", "rig:R3"]
    assert cfg["markers"]["board"]["names"] == ["board:B1", "board:B2", "board:B3"]
    assert f"# Use: cvsflow run {out}" in text and "camera 0 (the reference, C0) is cam_left" in text
    plain, rigs = assert_runnable_rig("bar", cfg)
    assert rigs["bar"]["shared_dirs"] == [c["shared_dir"] for c in cfg["cameras"]]
    assert plain["bar-cam_right"]["video"] == str(rec / "cam_right" / "video.mp4")
    assert "wrote" in capsys.readouterr().out


def test_init_rig_with_shared_views_in_a_top_level_folder(tmp_path):
    """rec/shared/<camera>/ serves as well; a shared folder without its camera is noted."""
    rec = make_rig(tmp_path / "rec", cameras=("a", "b", "c"), shared="top")
    _stills(rec / "shared" / "d", SHARED)
    session, notes = build_session_config(rec)
    assert [c["shared_dir"] for c in session["cameras"]] == [str(rec / "shared" / k) for k in "abc"]
    assert any(str(rec / "shared" / "d") in n and "no camera folder named d" in n for n in notes)
    assert_runnable_rig("r", session)


def test_init_rig_without_shared_views_notes_that_rig_extrinsics_will_not_run(tmp_path):
    session, notes = build_session_config(make_rig(tmp_path / "rec", shared=None))
    assert all("shared_dir" not in c for c in session["cameras"])
    assert any("rig_extrinsics will not run" in n for n in notes)
    assert_runnable_rig("r", session)


def test_init_rig_camera_without_video_or_with_two_videos_is_a_named_todo(tmp_path):
    rec = make_rig(tmp_path / "rec", cameras=("cam_a", "cam_b", "cam_c"), board=False)
    (rec / "cam_b" / "video.mp4").unlink()
    _video(rec / "cam_c" / "take2.mp4")
    _video(rec / "overview.mp4")
    session, notes = build_session_config(rec)
    videos = {c["name"]: c["video"] for c in session["cameras"]}
    assert videos == {"cam_a": str(rec / "cam_a" / "video.mp4"), "cam_b": "TODO", "cam_c": "TODO"}
    assert any(n.startswith(f"{rec / 'cam_b'}: no video") for n in notes)
    assert any(n.startswith(f"{rec / 'cam_c'}: 2 videos") and "take2.mp4, video.mp4" in n for n in notes)
    assert any("outside the camera folders" in n and "overview.mp4" in n for n in notes)
    # a camera folder with a video and shared views but no stills of its own is a camera too
    _video(rec / "cam_d" / "video.mp4")
    _stills(rec / "cam_d" / "shared", SHARED, board=False)
    session, notes = build_session_config(rec)
    cam_d = session["cameras"][-1]
    assert cam_d["name"] == "cam_d" and cam_d["calib_dir"] == "TODO"
    assert cam_d["shared_dir"] == str(rec / "cam_d" / "shared")
    assert any(n.startswith(f"{rec / 'cam_d'}: no folder with 3 or more stills") for n in notes)


def test_init_rig_shared_stills_must_pair_by_file_name(tmp_path):
    # one view missing in one camera: the other views pair, the unpaired one is named
    rec = make_rig(tmp_path / "r1", shared_names={"cam_right": SHARED + ["shared_003.png"]}, board=False)
    session, notes = build_session_config(rec)
    assert all("shared_dir" in c for c in session["cameras"])
    assert any("4 stills" in n and "3 file names in common" in n and "shared_003.png" in n for n in notes)
    # per-camera file names that never pair: no shared_dir anywhere, the folders named
    rec = make_rig(tmp_path / "r2", shared_names={"cam_left": [f"left_{i}.png" for i in range(3)],
                                                  "cam_right": [f"right_{i}.png" for i in range(3)]})
    session, notes = build_session_config(rec)
    assert all("shared_dir" not in c for c in session["cameras"])
    assert any(n.startswith(f"{rec / 'cam_right' / 'shared'}: only 0 shared stills") and
               str(rec / "cam_left" / "shared") in n for n in notes)
    assert_runnable_rig("r", session)
    # shared views in only one camera: left out of both, noted
    rec = make_rig(tmp_path / "r3", shared=None, board=False)
    _stills(rec / "cam_left" / "shared", SHARED)
    session, notes = build_session_config(rec)
    assert all("shared_dir" not in c for c in session["cameras"])
    assert any(n.startswith(f"{rec / 'cam_right'}: no folder of shared views") for n in notes)


def test_init_rig_contradictions_are_errors_naming_the_folders(tmp_path):
    rec = make_rig(tmp_path / "r1")
    _stills(rec / "shared" / "cam_left", SHARED)
    with pytest.raises(InputError, match="two folders of shared views") as exc:
        build_session_config(rec)
    assert str(rec / "cam_left" / "shared") in str(exc.value)
    rec = make_rig(tmp_path / "r2", cameras=("cam 1", "cam_1"), shared=None)
    with pytest.raises(InputError, match="not distinct"):
        build_session_config(rec)


def test_init_one_camera_in_subfolders_stays_a_plain_session(tmp_path):
    """Stills in two subfolders with the video beside them, or stills and video in separate
    subfolders, are one camera as before; two camera folders without any video are too."""
    rec = tmp_path / "rec"
    _stills(rec / "calib_a", ["a0.png", "a1.png", "a2.png", "a3.png"], board=False)
    _stills(rec / "calib_b", ["b0.png", "b1.png", "b2.png"], board=False)
    _video(rec / "video" / "take.mp4")
    assert camera_folders(rec) == []
    session, _ = build_session_config(rec)
    assert session["calib_dir"] == str(rec / "calib_a") and session["video"] == str(rec / "video" / "take.mp4")
    assert "cameras" not in session


REAL = Path("/work/shared/data/real/opencv-chessboard")


@pytest.mark.skipif(not REAL.is_dir(), reason="OpenCV sample stills not on this machine")
def test_init_rig_from_the_opencv_sample_stills(tmp_path):
    """OpenCV's real stills (9x6 inner corners) split between two camera folders: the board is
    found (10x7 squares) and the shared copies pair by name."""
    import shutil

    real = sorted(REAL.glob("left*.jpg"))
    rec = tmp_path / "rec"
    for c, cam in enumerate(("c0", "c1")):
        (rec / cam / "calib").mkdir(parents=True)
        (rec / cam / "shared").mkdir()
        for p in real[5 * c:5 * c + 5]:
            shutil.copy(p, rec / cam / "calib" / p.name)
        for p in real[-3:]:
            shutil.copy(p, rec / cam / "shared" / p.name)
        _video(rec / cam / "video.mp4")
    _mocap(rec / "take.csv")
    session, notes = build_session_config(rec)
    assert session["board"] == {"squares_x": 10, "squares_y": 7, "square_m": "TODO"}
    assert [c["shared_dir"] for c in session["cameras"]] == [str(rec / k / "shared") for k in ("c0", "c1")]
    assert_runnable_rig("real", session)


def test_init_mono_and_rig_flags_override_the_guess(tmp_path):
    """--mono on a rig folder gives one camera's session; --rig on a one-camera folder is an
    error saying what a rig folder needs, and writes nothing."""
    rec = make_rig(tmp_path / "rec")
    out = tmp_path / "mono.yaml"
    assert cli.main(["init", str(rec), "--out", str(out), "--mono"]) == 0
    cfg = next(iter(yaml.safe_load(out.read_text())["sessions"].values()))
    assert "cameras" not in cfg
    assert cfg["calib_dir"].startswith(str(rec / "cam_left"))
    assert cfg["video"] == str(rec / "cam_left" / "video.mp4")
    one = tmp_path / "one"
    _stills(one / "calib", ["a.png", "b.png", "c.png"])
    with pytest.raises(InputError, match="not a rig recording: expected two or more camera folders"):
        build_session_config(one, "rig")
    out2 = tmp_path / "rig.yaml"
    assert cli.main(["init", str(one), "--out", str(out2), "--rig"]) == 1
    assert not out2.exists()
