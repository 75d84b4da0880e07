"""OptiTrack and Qualisys exports through the workflow's vicon stages, against the Vicon path.

A short rendered session is run to its bodies table (the Vicon path: Nexus CSV, gap repair,
rigid-body fit). Its markers and fitted bodies are then written as a Motive CSV (markers and
rigid bodies, millimetres) and as QTM TSVs (3D current layout; 6D old layout), and four
sessions read them: Motive and QTM markers fitted by cvsflow (bodies_from: markers) and the
systems' own rigid bodies (bodies_from: system). Every one must give the Vicon path's body poses.
"""

from __future__ import annotations

import copy

import numpy as np
import pandas as pd
import pytest

from cvsflow.io.mocap.formats import read_markers
from cvsflow.io.mocap.optitrack import write_motive_csv
from cvsflow.io.mocap.qualisys import write_qtm_tsv
from cvsflow.mocap.bodies import body_poses

from .test_workflow import demo_config, dry_run_jobs, snakemake, write_config

SYSTEM = {"camera": "cam_rb", "board": "board_rb"}


def _renamed(bodies):
    out = bodies.copy()
    out["body"] = out["body"].map(SYSTEM)
    out.attrs = dict(bodies.attrs)
    return out


def _assert_same_bodies(a, b, pos_m, rot_rad, where):
    for body in ("camera", "board"):
        t0, T0, v0 = body_poses(a, body)
        t1, T1, v1 = body_poses(b, body)
        np.testing.assert_allclose(t1, t0, atol=1e-9, err_msg=where)
        np.testing.assert_array_equal(v1, v0, err_msg=where)
        assert v0.sum() > 0.9 * len(v0), where
        assert np.abs(T1[v1, :3, 3] - T0[v0, :3, 3]).max() < pos_m, where
        R = np.einsum("nji,njk->nik", T0[v0, :3, :3], T1[v1, :3, :3])
        ang = np.arccos(np.clip((np.trace(R, axis1=1, axis2=2) - 1) / 2, -1, 1))
        assert ang.max() < rot_rad, where


@pytest.mark.slow
def test_motive_and_qtm_sessions_match_the_vicon_path(tmp_path):
    """Motive / QTM exports of a rendered session give its Vicon-path body poses, fitted or from the system."""
    config = demo_config(duration_s=5.0)
    config["flights"] = {}
    write_config(tmp_path, config)
    snakemake(tmp_path, "results/demo/bodies.parquet")
    markers = read_markers(tmp_path / "data/demo/vicon.csv")
    ref = pd.read_parquet(tmp_path / "results/demo/bodies.parquet")
    ref.attrs["rate_hz"] = markers.attrs["rate_hz"]
    data = tmp_path / "data"
    write_motive_csv(data / "motive.csv", markers, _renamed(ref), units="Millimeters")
    write_qtm_tsv(data / "qtm.tsv", markers=markers, layout="current")
    write_qtm_tsv(data / "qtm_6d.tsv", bodies=_renamed(ref), layout="old")

    demo = config["sessions"]["demo"]
    base = {"video": "data/demo/video.mp4", "camera": "demo", "board": dict(demo["board"])}
    system_markers = {b: {"system_body": name} for b, name in SYSTEM.items()}
    sessions = {
        "motive_markers": {"mocap": {"file": "data/motive.csv", "format": "motive_csv"},
                           "markers": copy.deepcopy(demo["markers"])},
        "motive_system": {"mocap": {"file": "data/motive.csv", "bodies_from": "system"},
                          "markers": copy.deepcopy(system_markers)},
        "qtm_markers": {"mocap": {"file": "data/qtm.tsv"}, "markers": copy.deepcopy(demo["markers"])},
        "qtm_system": {"mocap": {"file": "data/qtm_6d.tsv", "format": "qtm_tsv", "bodies_from": "system"},
                       "markers": copy.deepcopy(system_markers)},
    }
    for name, s in sessions.items():
        config["sessions"][name] = {**copy.deepcopy(base), **s}
    write_config(tmp_path, config)

    # the system sessions read the export directly: no marker import or repair is scheduled
    jobs = dry_run_jobs(tmp_path, "results/motive_system/bodies.parquet", "results/qtm_system/bodies.parquet")
    assert jobs == {"mocap_bodies"}

    targets = [f"results/{s}/bodies_30hz.parquet" for s in ["demo", *sessions]]
    snakemake(tmp_path, *targets)
    got = {s: pd.read_parquet(tmp_path / f"results/{s}/bodies.parquet") for s in sessions}
    # markers re-fitted: the exports hold the markers to 1e-9 m (Motive mm, 6 decimals) or 1e-8 m
    _assert_same_bodies(ref, got["motive_markers"], 1e-6, 1e-5, "motive_markers")
    _assert_same_bodies(ref, got["qtm_markers"], 1e-6, 1e-5, "qtm_markers")
    # the system's poses: quaternion to 6 decimals (Motive), rotation matrix to 5 (QTM)
    _assert_same_bodies(ref, got["motive_system"], 1e-6, 5e-6, "motive_system")
    _assert_same_bodies(ref, got["qtm_system"], 1e-6, 5e-5, "qtm_system")
    # the system's residual is carried along as fit_rms_m
    for s in ("motive_system", "qtm_system"):
        for body in ("camera", "board"):
            a = ref[ref["body"] == body]
            b = got[s][got[s]["body"] == body]
            ok = a["valid"].to_numpy()
            np.testing.assert_allclose(b["fit_rms_m"].to_numpy()[ok], a["fit_rms_m"].to_numpy()[ok], atol=2e-8)
    # and at the video rate (block means of rate / fps samples)
    ref30 = pd.read_parquet(tmp_path / "results/demo/bodies_30hz.parquet")
    for s in sessions:
        lo = pd.read_parquet(tmp_path / f"results/{s}/bodies_30hz.parquet")
        _assert_same_bodies(ref30, lo, 1e-6, 5e-5, f"{s} 30 Hz")


def test_system_session_without_system_body_is_refused(tmp_path):
    """bodies_from: system without markers.<body>.system_body stops at parse time, naming the key."""
    config = demo_config()
    config["sessions"]["lab"] = {
        "mocap": {"file": "data/lab/take.csv", "bodies_from": "system"},
        "board": {"squares_x": 6, "squares_y": 5, "square_m": 0.09},
        "markers": {"camera": {"system_body": "cam"}, "board": {"names": ["b1", "b2", "b3"]}},
    }
    write_config(tmp_path, config)
    proc = snakemake(tmp_path, "-n", check=False)
    assert proc.returncode != 0
    assert "sessions.lab.markers.board: mocap.bodies_from is system, so system_body is needed" in (
        proc.stdout + proc.stderr)
