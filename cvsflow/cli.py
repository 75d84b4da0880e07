"""The ``cvsflow`` command: calibrate stills, export results, run the workflow, start a session.

Exit codes: 0 success; 1 a cvsflow error (one line on stderr naming the file); 2 a usage error
(argparse); any other code from ``cvsflow run`` is snakemake's own.
"""

from __future__ import annotations

import argparse
import logging
import re
import subprocess
import sys
from pathlib import Path

import numpy as np

from cvsflow.errors import CvsflowError, InputError

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")
MOCAP_SUFFIXES = (".csv", ".c3d", ".tsv")
#: Inner-corner sizes ``cvsflow init`` tries (OpenCV sample, common printed boards, the demo's).
COMMON_INNER = ((9, 6), (8, 6), (7, 5), (7, 6), (10, 7), (6, 4), (5, 4), (11, 8), (8, 5))

EPILOG = """\
examples:
  cvsflow calibrate stills/ --inner 9x6 --square-m 0.025 --out calib/
  cvsflow export camera results/demo --format kalibr --out camchain.yaml
  cvsflow export trajectory results/demo --out-dir traj/
  cvsflow init recordings/lab1 --out my_session.yaml
  cvsflow run --cores 2 --configfile my_session.yaml results/lab1/comparison.yaml
`cvsflow COMMAND --help` explains each command's options.

board convention: cvsflow's config counts SQUARES (board.squares_x, squares_y); OpenCV and
Kalibr count INNER CORNERS (one fewer each way). `--inner 9x6` is 10x7 squares.

exit codes: 0 ok, 1 cvsflow error (one line naming the file), 2 usage error;
`cvsflow run` returns snakemake's exit code.
"""


def _parse_inner(text: str) -> tuple[int, int]:
    try:
        nx, ny = (int(v) for v in text.lower().split("x"))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(f"--inner {text!r}: expected NXxNY, e.g. 9x6") from exc
    if nx < 2 or ny < 2:
        raise argparse.ArgumentTypeError(f"--inner {text!r}: expected at least 2x2 inner corners")
    return nx, ny


# ------------------------------------------------------------------------------------------
# calibrate
# ------------------------------------------------------------------------------------------


def cmd_calibrate(args) -> int:
    """``cvsflow calibrate``: calibrate a camera from a folder of chessboard stills.

    Writes ``camera.yaml``, ``calib_corners.parquet`` (docs/contracts.md) and the OpenCV,
    Kalibr and ROS camera files into ``args.out``, and prints the intrinsics (px) and RMS.

    Parameters
    ----------
    args : argparse.Namespace
        ``dir`` (stills folder), ``inner`` ((nx, ny) inner corners), ``square_m`` (square
        side, m), ``out`` (output folder), ``subpix_window_px``, ``min_images``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No images in ``dir`` (or an unreadable one).
    CalibrationError
        Too few stills with a board, or the calibration failed.
    """
    import cv2

    from cvsflow.calibration import calibrate_camera
    from cvsflow.io import write_parquet, write_yaml
    from cvsflow.io.camera_formats import write_all_formats
    from cvsflow.io.media import list_stills, read_gray

    nx, ny = args.inner
    board = {"squares_x": nx + 1, "squares_y": ny + 1, "square_m": float(args.square_m)}
    cv2.setNumThreads(1)
    paths = list_stills(args.dir)
    if not paths:
        raise InputError(f"{args.dir}: no images (png, jpg, ...) in the stills folder")
    images = [(p.name, read_gray(p)) for p in paths]
    camera, corners = calibrate_camera(
        images, board, subpix_window_px=args.subpix_window_px, min_images=args.min_images
    )
    out = Path(args.out)
    write_yaml(camera, out / "camera.yaml")
    write_parquet(corners, out / "calib_corners.parquet")
    files = write_all_formats(camera, out)
    K = np.asarray(camera["K"])
    print(
        f"calibrated on {camera['n_used']} of {len(paths)} stills: fx {K[0, 0]:.5f} fy {K[1, 1]:.5f} "
        f"cx {K[0, 2]:.5f} cy {K[1, 2]:.5f} px, RMS {camera['rms_px']:.6f} px"
    )
    print(f"wrote {out / 'camera.yaml'}, " + ", ".join(str(p) for p in files.values()))
    return 0


# ------------------------------------------------------------------------------------------
# export
# ------------------------------------------------------------------------------------------


def _camera_yaml_path(src) -> Path:
    src = Path(src)
    path = src / "camera.yaml" if src.is_dir() else src
    if not path.is_file():
        raise InputError(f"{path}: camera.yaml not found (give a results/<session> folder or the file)")
    return path


def cmd_export_camera(args) -> int:
    """``cvsflow export camera``: a camera.yaml as OpenCV, Kalibr or ROS file.

    Parameters
    ----------
    args : argparse.Namespace
        ``src`` (a results/<session> folder or a camera.yaml), ``format`` (opencv, kalibr,
        ros), ``out`` (output file).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No camera.yaml at ``src``, or a malformed one.
    """
    from cvsflow.io import read_yaml
    from cvsflow.io.camera_formats import write_camera_format

    path = _camera_yaml_path(args.src)
    write_camera_format(read_yaml(path), args.format, args.out)
    print(f"wrote {args.out} ({args.format}) from {path}")
    return 0


def _tum_frame(t_s, T):
    """Common trajectory form (``t_s``, ``x_m..z_m``, ``qx..qw``) of (N, 4, 4) transforms."""
    import pandas as pd

    from cvsflow.transforms import quat_from_R

    q = quat_from_R(T[:, :3, :3]).reshape(-1, 4)
    d = pd.DataFrame({"t_s": np.asarray(t_s, dtype=float)})
    for k, a in enumerate("xyz"):
        d[f"{a}_m"] = T[:, k, 3]
    for k, a in enumerate(("qx", "qy", "qz", "qw")):
        d[a] = q[:, k]
    return d


def session_trajectories(pairs, se3_result=None):
    """The unaligned trajectories of a session, as (N, 4, 4) transforms on the video clock.

    Parameters
    ----------
    pairs : DataFrame
        pairs.parquet (``t_s``, ``cvs_rvec_*``, ``cvs_{x,y,z}_m``, ``cmbm_*``).
    se3_result : dict, optional
        The se3 result.yaml: its mountings ``T_Cm_C`` and ``T_Bm_B`` map the Vicon pose into
        the camera optical and board frames.

    Returns
    -------
    dict
        ``cvs_T_C_B`` (PnP), ``vicon_T_Cm_Bm`` (Vicon, marker bodies) and with ``se3_result``
        ``vicon_T_C_B`` = T_Cm_C⁻¹ T_Cm_Bm T_Bm_B: the Vicon reference in the frames of the CVS
        estimate, so that ``evo_ape tum vicon_T_C_B.tum cvs_T_C_B.tum`` compares like with like.
    """
    from cvsflow.transforms import R_from_quat, R_from_rvec, invert_T, make_T

    rvec = pairs[["cvs_rvec_0", "cvs_rvec_1", "cvs_rvec_2"]].to_numpy(float)
    T_C_B = make_T(R_from_rvec(rvec), pairs[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy(float))
    q = pairs[[f"cmbm_q{a}" for a in "xyzw"]].to_numpy(float)
    T_Cm_Bm = make_T(R_from_quat(q), pairs[["cmbm_x_m", "cmbm_y_m", "cmbm_z_m"]].to_numpy(float))
    out = {"cvs_T_C_B": T_C_B.reshape(-1, 4, 4), "vicon_T_Cm_Bm": T_Cm_Bm.reshape(-1, 4, 4)}
    if se3_result is not None:
        T_C_Cm = invert_T(np.asarray(se3_result["T_Cm_C"], dtype=float))
        T_Bm_B = np.asarray(se3_result["T_Bm_B"], dtype=float)
        out["vicon_T_C_B"] = T_C_Cm @ out["vicon_T_Cm_Bm"] @ T_Bm_B
    return out


def cmd_export_trajectory(args) -> int:
    """``cvsflow export trajectory``: a session's CVS and Vicon trajectories as TUM files.

    Writes ``cvs_T_C_B.tum``, ``vicon_T_Cm_Bm.tum`` and, when an se3 result.yaml is found,
    ``vicon_T_C_B.tum`` (see :func:`session_trajectories`): video clock (s), m, scalar-last
    quaternions, unaligned.

    Parameters
    ----------
    args : argparse.Namespace
        ``results`` (a results/<session> folder or its pairs.parquet), ``out_dir``, ``se3``
        (a result.yaml, or None for ``RESULTS/se3/calib/result.yaml`` when present).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No pairs.parquet, missing pairs columns, a given ``se3`` file missing, or one without
        ``T_Cm_C`` and ``T_Bm_B``.
    """
    from cvsflow.io import read_parquet, read_yaml
    from cvsflow.io.flightlog import write_tum

    src = Path(args.results)
    path = src / "pairs.parquet" if src.is_dir() else src
    if not path.is_file():
        raise InputError(f"{path}: pairs.parquet not found (give a finished results/<session> folder)")
    pairs = read_parquet(path)
    need = {"t_s", "cvs_rvec_0", "cvs_rvec_1", "cvs_rvec_2", "cvs_x_m", "cvs_y_m", "cvs_z_m",
            "cmbm_x_m", "cmbm_y_m", "cmbm_z_m", "cmbm_qx", "cmbm_qy", "cmbm_qz", "cmbm_qw"}
    if not need <= set(pairs.columns):
        missing = sorted(need - set(pairs.columns))
        raise InputError(f"{path}: missing columns {missing} (docs/contracts.md, pairs.parquet)")
    se3_path = Path(args.se3) if args.se3 else path.parent / "se3" / "calib" / "result.yaml"
    if args.se3 and not se3_path.is_file():
        raise InputError(f"{se3_path}: se3 result.yaml not found")
    se3 = read_yaml(se3_path) if se3_path.is_file() else None
    if se3 is not None and not {"T_Cm_C", "T_Bm_B"} <= set(se3):
        raise InputError(f"{se3_path}: expected the keys T_Cm_C and T_Bm_B (an se3 result.yaml)")
    out = Path(args.out_dir)
    t_s = pairs["t_s"].to_numpy(float)
    written = []
    for name, T in session_trajectories(pairs, se3).items():
        write_tum(_tum_frame(t_s, T), out / f"{name}.tum")
        written.append(str(out / f"{name}.tum"))
    print(f"wrote {', '.join(written)} ({len(pairs)} poses each, video clock, unaligned)")
    if se3 is None:
        print(f"no {se3_path}: vicon_T_C_B.tum (the Vicon in the CVS frames) not written; the "
              "two files differ by T_Cm_C and T_Bm_B, which evo's one-sided -a cannot remove")
    else:
        print(f"compare: evo_ape tum {out / 'vicon_T_C_B.tum'} {out / 'cvs_T_C_B.tum'} "
              f"(mountings from {se3_path}; add -a or -s for evo's own alignment)")
    return 0


# ------------------------------------------------------------------------------------------
# run
# ------------------------------------------------------------------------------------------


def profile_dir(root: Path) -> Path:
    """``profiles/default`` at the repository root if present, else ``workflow/profiles/default``.

    Parameters
    ----------
    root : Path
        The repository root (the folder ``cvsflow run`` is run from).

    Returns
    -------
    Path
        The Snakemake profile folder (not checked to exist in the fallback case).
    """
    top = root / "profiles" / "default"
    return top if top.is_dir() else root / "workflow" / "profiles" / "default"


def cmd_run(args, extra) -> int:
    """``cvsflow run``: run ``python -m snakemake`` with the workstation profile.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed ``run`` command (only ``verbose``; nothing else is parsed).
    extra : list of str
        Every argument after ``run``, passed to snakemake unchanged; ``--profile
        <profile_dir>`` is added unless it has ``--profile`` or ``--workflow-profile``.

    Returns
    -------
    int
        Snakemake's exit code.

    Raises
    ------
    InputError
        No Snakefile in the current folder or its ``workflow/``.
    """
    root = Path.cwd()
    if not (root / "Snakefile").is_file() and not (root / "workflow" / "Snakefile").is_file():
        raise InputError(f"{root}: no Snakefile here (run `cvsflow run` from the cvsflow repository)")
    cmd = [sys.executable, "-m", "snakemake"]
    if "--profile" not in extra and "--workflow-profile" not in extra:
        cmd += ["--profile", str(profile_dir(root).relative_to(root))]
    cmd += list(extra)
    log.info("running %s", " ".join(cmd))
    return subprocess.call(cmd)


# ------------------------------------------------------------------------------------------
# init
# ------------------------------------------------------------------------------------------


def _find_stills(folder: Path):
    from cvsflow.io.media import IMAGE_SUFFIXES

    best = None
    for d in sorted([folder, *[p for p in folder.rglob("*") if p.is_dir()]]):
        n = sum(1 for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)
        if n >= 3 and (best is None or n > best[1]):
            best = (d, n)
    return best


def _try_inner_sizes(still: Path):
    import cv2

    from cvsflow.io.media import read_gray

    gray = read_gray(still)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    for nx, ny in COMMON_INNER:
        found, _ = cv2.findChessboardCorners(gray, (nx, ny), flags=flags)
        if found:
            return nx, ny
    return None


def build_session_config(folder) -> tuple[dict, list[str]]:
    """Session config guessed from a recording folder, and notes for the user to check.

    Parameters
    ----------
    folder : str or Path
        The recording folder, searched recursively for a stills folder (3 or more images),
        a video (``VIDEO_SUFFIXES``) and a motion-capture export (``MOCAP_SUFFIXES``).

    Returns
    -------
    session : dict
        ``calib_dir``, ``video``, ``vicon``, ``board``, ``markers`` (entries marked TODO where
        nothing was found).
    notes : list of str
        What was found and what the user must check.
    """
    from cvsflow.io.markers import marker_names
    from cvsflow.io.mocap_formats import read_mocap

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: recording folder not found")
    notes = []
    session: dict = {}
    stills = _find_stills(folder)
    inner = None
    if stills is None:
        session["calib_dir"] = "TODO"
        notes.append("no folder with 3 or more stills found: set calib_dir")
    else:
        session["calib_dir"] = str(stills[0])
        notes.append(f"stills: {stills[0]} ({stills[1]} images)")
        from cvsflow.io.media import list_stills

        # The first stills may not show the whole board: try a few before giving up.
        tried = list_stills(stills[0])[:5]
        found = [size for size in map(_try_inner_sizes, tried) if size is not None]
        if found:
            inner = max(set(found), key=found.count)
            notes.append(f"board found on {found.count(inner)} of the first {len(tried)} stills")
    videos = sorted(p for p in folder.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES)
    session["video"] = str(videos[0]) if videos else "TODO"
    notes.append(f"video: {videos[0]}" if videos else "no video found: set video")
    if len(videos) > 1:
        notes.append(f"{len(videos)} videos found; took the first, check")
    mocap = sorted(p for p in folder.rglob("*") if p.suffix.lower() in MOCAP_SUFFIXES)
    names: list[str] = []
    system_bodies: list[str] = []
    session["vicon"] = "TODO"
    for p in mocap:
        try:
            export = read_mocap(p)
        except CvsflowError as exc:
            notes.append(f"{p}: not a motion-capture export ({exc})")
            continue
        names = marker_names(export.markers)
        if export.bodies is not None and len(export.bodies):
            system_bodies = list(dict.fromkeys(export.bodies["body"]))
        session["vicon"] = str(p)
        session["mocap"] = {"format": export.format}
        solved = f", bodies solved by the system: {', '.join(system_bodies)}" if system_bodies else ""
        notes.append(f"motion capture: {p} ({export.format}), markers {', '.join(names) or 'none'}{solved}")
        break
    if session["vicon"] == "TODO":
        notes.append("no Nexus CSV, C3D, Motive CSV or QTM TSV export found: set vicon")
    if inner is None:
        session["board"] = {"squares_x": "TODO", "squares_y": "TODO", "square_m": "TODO"}
        notes.append(f"no chessboard of the sizes {COMMON_INNER} (inner corners) found: set board")
    else:
        session["board"] = {"squares_x": inner[0] + 1, "squares_y": inner[1] + 1, "square_m": "TODO"}
        notes.append(
            f"board: {inner[0]}x{inner[1]} inner corners found = {inner[0] + 1}x{inner[1] + 1} squares "
            "(cvsflow counts squares); measure square_m in metres"
        )
    subjects: dict[str, list[str]] = {}
    for n in names:
        subjects.setdefault(n.split(":")[0] if ":" in n else "(no subject)", []).append(n)
    if subjects:
        notes.append("subjects in the export: " + "; ".join(
            f"{k} ({len(v)} markers)" for k, v in subjects.items()))
    cam = next((v for k, v in subjects.items() if "cam" in k.lower()), ["TODO"])
    brd = next((v for k, v in subjects.items() if "board" in k.lower() or "chess" in k.lower()),
               ["TODO"])
    for body, chosen in (("camera", cam), ("board", brd)):
        if chosen == ["TODO"] and names:
            notes.append(f"no subject named like the {body}: pick its markers from the list above")
        elif 0 < len(chosen) < 3:
            notes.append(f"{body}: {len(chosen)} markers; a rigid body needs at least 3")
    # No layout_m: the vicon stage learns it from the first still second of the take; a
    # measured layout (one [x, y, z] per name, metres, body frame) can be added.
    notes.append("markers.*.layout_m left out: learned from the first still second of the take "
                 "(add your measured layout, m, to use it instead)")
    session["markers"] = {"camera": {"names": cam}, "board": {"names": brd}}
    if system_bodies and not names:
        # A 6DOF-only export: the system's own bodies are all there is.
        session["mocap"]["bodies_from"] = "system"
        def guess(keys):
            return next((b for b in system_bodies if any(k in b.lower() for k in keys)), "TODO")

        session["markers"] = {"camera": {"system_body": guess(("cam",))},
                              "board": {"system_body": guess(("board", "chess"))}}
        notes[-1] = ("the export has no markers: mocap.bodies_from is system; check "
                     "markers.*.system_body against the bodies listed above")
    elif system_bodies:
        notes.append("the export also has the system's own bodies: set mocap.bodies_from: system "
                     "and markers.<body>.system_body to use them instead of fitting the markers")
    return session, notes


def cmd_init(args) -> int:
    """``cvsflow init``: write a session config guessed from a recording folder.

    The YAML (``sessions: {name: ...}``) is preceded by comment lines with the notes of
    :func:`build_session_config`; the notes are printed too.

    Parameters
    ----------
    args : argparse.Namespace
        ``dir`` (recording folder), ``out`` (file to write, default
        ``DIR/cvsflow_session.yaml``), ``name`` (session name, default the folder's name;
        characters other than letters, digits, _ and - become _).

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        ``out`` exists (never overwritten), or ``dir`` is not a folder.
    """
    import yaml

    from cvsflow.io import atomic_output

    folder = Path(args.dir)
    out = Path(args.out) if args.out else folder / "cvsflow_session.yaml"
    if out.exists():
        raise InputError(f"{out}: exists; cvsflow init never overwrites a file (give --out)")
    session, notes = build_session_config(folder)
    # A session name is a wildcard value: letters, digits, _ and - only (workflow/rules/common.smk).
    name = re.sub(r"[^A-Za-z0-9_-]", "_", args.name or folder.resolve().name)
    text = "# Session config written by `cvsflow init`: check every line, fill every TODO.\n"
    text += "# Use: cvsflow run --configfile " + str(out) + "\n"
    text += ("# It MERGES with config/config.yaml: the demo session and flight run too unless you\n"
             "# name your targets (results/" + name + "/comparison.yaml); see the README.\n")
    text += "".join(f"# {n}\n" for n in notes)
    text += yaml.safe_dump({"sessions": {name: session}}, sort_keys=False, default_flow_style=None)
    with atomic_output(out) as tmp:
        Path(tmp).write_text(text)
    for n in notes:
        print(n)
    print(f"wrote {out}")
    return 0


# ------------------------------------------------------------------------------------------
# handeye
# ------------------------------------------------------------------------------------------


def cmd_handeye(args) -> int:
    """``cvsflow handeye``: hand-eye calibration from stills with one carrier pose each.

    Writes ``OUT/handeye.yaml`` (the result of :func:`cvsflow.handeye.calibrate_hand_eye`
    plus the command's inputs and the pairing rule) and prints ``T_Cm_C`` (eye-in-hand) or
    ``T_W_C`` (eye-to-hand) with its standard errors (mm, deg).

    Parameters
    ----------
    args : argparse.Namespace
        ``stills``, ``poses`` (file or glob), ``pose_format``, ``csv_spec``, ``inner``,
        ``square_m`` (m), ``camera`` (known intrinsics file), ``out``, ``eye_to_hand``,
        ``method``, ``free_intrinsics`` (comma separated), ``exact_poses``,
        ``pose_sigma_mm``, ``pose_sigma_deg``, ``subpix_window_px``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No images, unreadable poses or camera, stills and poses that cannot be paired.
    CalibrationError
        Too few usable stills or motions, or the fit failed.
    """
    import cv2

    from cvsflow.handeye import calibrate_hand_eye, pair_stills_with_poses
    from cvsflow.io import read_yaml, write_yaml
    from cvsflow.io.media import list_stills, read_gray
    from cvsflow.io.poses import natural_key, pose_table_T, read_pose_list
    from cvsflow.io.visp import read_known_camera

    nx, ny = args.inner
    board = {"squares_x": nx + 1, "squares_y": ny + 1, "square_m": float(args.square_m)}
    cv2.setNumThreads(1)
    paths = sorted(list_stills(args.stills), key=lambda p: natural_key(p.name))
    if not paths:
        raise InputError(f"{args.stills}: no images (png, jpg, ...) in the stills folder")
    spec = read_yaml(args.csv_spec) if args.csv_spec else None
    poses = read_pose_list(args.poses, args.pose_format, spec)
    pose_idx, rule = pair_stills_with_poses([p.name for p in paths], poses["name"])
    T_all = pose_table_T(poses)
    T_W_X = np.stack([T_all[k] if k >= 0 else np.full((4, 4), np.nan) for k in pose_idx])
    origins = [poses["origin"].iloc[k] if k >= 0 else "none" for k in pose_idx]
    unused = len(poses) - len({k for k in pose_idx if k >= 0})
    if unused:
        log.warning("%d of %d poses pair with no still (%s)", unused, len(poses), rule)
    free = [n.strip() for n in args.free_intrinsics.split(",") if n.strip()]
    res = calibrate_hand_eye(
        [(p.name, read_gray(p)) for p in paths], T_W_X, board, read_known_camera(args.camera),
        mode="eye_to_hand" if args.eye_to_hand else "eye_in_hand", method=args.method,
        free_intrinsics=free, pose_noise=not args.exact_poses,
        pose_sigma_m=None if args.pose_sigma_mm is None else 1e-3 * args.pose_sigma_mm,
        pose_sigma_rad=None if args.pose_sigma_deg is None else np.radians(args.pose_sigma_deg),
        subpix_window_px=args.subpix_window_px, pose_names=origins,
    )  # fmt: skip
    res = {"command": "cvsflow handeye", "camera": str(args.camera), "poses": str(args.poses),
           "pose_format": args.pose_format, "pairing": rule, **res}  # fmt: skip
    out = Path(args.out) / "handeye.yaml"
    write_yaml(res, out)
    name = "T_W_C" if args.eye_to_hand else "T_Cm_C"
    T, sd = np.asarray(res[name]), res["std"][name]
    print(
        f"{name}: t = [{', '.join(f'{v:.5f}' for v in T[:3, 3])}] m "
        f"(+- {sd['x_mm']:.2f}, {sd['y_mm']:.2f}, {sd['z_mm']:.2f} mm), rotation +- "
        f"{sd['rotation_deg']:.3f} deg; {res['n_used']} of {res['n_stills']} stills, "
        f"RMS {res['rms_px']:.3f} px"
    )
    print(f"wrote {out}")
    return 0


def _add_handeye_parser(sub) -> None:
    h = sub.add_parser(
        "handeye",
        help="hand-eye calibration (T_Cm_C) from chessboard stills with one carrier pose each",
        description="Stills of a chessboard, each with a pose of the camera's carrier (robot "
        "end-effector or marker body). Eye-in-hand (default: camera on the carrier, board "
        "fixed) gives T_Cm_C and T_W_B; --eye-to-hand (board on the carrier, camera fixed) "
        "gives T_W_C and T_Bm_B. Closed-form start (OpenCV), then corner reprojection with the "
        "carrier poses' own errors estimated; writes OUT/handeye.yaml.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    h.add_argument("--stills", required=True, help="folder of stills (png, jpg, ...)")
    h.add_argument("--poses", required=True, help="pose file(s), a quoted glob for one file per still")
    h.add_argument("--pose-format", choices=("visp", "tum", "csv", "auto"), default="auto",
                   help="visp: vpPoseVector YAML (m, theta-u rad); tum: t tx ty tz qx qy qz qw; "
                   "csv: columns and units in --csv-spec; auto (default): from the file")  # fmt: skip
    h.add_argument("--csv-spec", help="YAML of the CSV's columns and units (time_col, pos_cols, "
                   "pos_unit, rot, rot_cols, angle_unit, name_col)")  # fmt: skip
    h.add_argument("--inner", type=_parse_inner, required=True, help="inner corners NXxNY, e.g. 9x6")
    h.add_argument("--square-m", type=float, required=True, help="square side, metres")
    h.add_argument("--camera", required=True,
                   help="known intrinsics: ViSP camera XML, cvsflow camera.yaml or OpenCV YAML")
    h.add_argument("--out", required=True, help="output folder")
    h.add_argument("--eye-to-hand", action="store_true",
                   help="board on the carrier, camera fixed in the world")
    h.add_argument("--method", default="park",
                   choices=("tsai", "park", "horaud", "andreff", "daniilidis", "shah", "li"),
                   help="closed-form start (default park)")
    h.add_argument("--free-intrinsics", default="",
                   help="intrinsics refined too, comma separated, e.g. fx,fy,cx,cy (default none)")
    h.add_argument("--exact-poses", action="store_true",
                   help="take the carrier poses as exact (no pose-error model)")
    h.add_argument("--pose-sigma-mm", type=float, help="known carrier position sigma (mm)")
    h.add_argument("--pose-sigma-deg", type=float, help="known carrier rotation sigma (deg)")
    h.add_argument("--subpix-window-px", type=int, default=11, help="cornerSubPix half window (px)")
    h.set_defaults(func=cmd_handeye)


# ------------------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``cvsflow`` command and its subcommands.

    Returns
    -------
    argparse.ArgumentParser
        Subcommands ``calibrate``, ``export camera``, ``export trajectory``, ``run``,
        ``init``, ``handeye``; each sets ``func`` to its ``cmd_*`` handler (None for ``run``,
        which :func:`main` handles).
    """
    p = argparse.ArgumentParser(
        prog="cvsflow",
        description="Webcam + chessboard pose accuracy against Vicon: calibrate, export, run, init.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO) on stderr")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    c = sub.add_parser(
        "calibrate",
        help="calibrate a camera from a folder of chessboard stills",
        description="Calibrate from stills alone (the workflow's calibrate stage); writes "
        "camera.yaml, calib_corners.parquet and the OpenCV, Kalibr and ROS files into OUT.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument("dir", help="folder of stills (png, jpg, ...)")
    c.add_argument("--inner", type=_parse_inner, required=True, help="inner corners NXxNY, e.g. 9x6")
    c.add_argument("--square-m", type=float, required=True, help="square side, metres")
    c.add_argument("--out", required=True, help="output folder")
    c.add_argument("--subpix-window-px", type=int, default=11, help="cornerSubPix half window (px)")
    c.add_argument("--min-images", type=int, default=5, help="fewest stills with a board")
    c.set_defaults(func=cmd_calibrate)

    e = sub.add_parser("export", help="export a finished run's camera or trajectories")
    esub = e.add_subparsers(dest="what", required=True, metavar="WHAT")
    ec = esub.add_parser(
        "camera",
        help="camera.yaml as OpenCV FileStorage, Kalibr camchain or ROS camera_info",
        description="Kalibr's radtan model has no k3: it is dropped; the largest pixel shift "
        "that causes is written in the file and warned about above 0.1 px.",
    )
    ec.add_argument("src", help="results/<session> folder or a camera.yaml")
    ec.add_argument("--format", choices=("opencv", "kalibr", "ros"), required=True)
    ec.add_argument("--out", required=True, help="output file")
    ec.set_defaults(func=cmd_export_camera)
    et = esub.add_parser(
        "trajectory",
        help="CVS and Vicon trajectories of a session as unaligned TUM files, for evo",
        description="From pairs.parquet, on the video clock (s, m, quaternion xyzw), unaligned: "
        "cvs_T_C_B.tum (PnP), vicon_T_Cm_Bm.tum (the Vicon, marker bodies) and, when the "
        "session has an se3 result, vicon_T_C_B.tum = T_Cm_C^-1 T_Cm_Bm T_Bm_B (the Vicon in "
        "the CVS frames). Compare with `evo_ape tum vicon_T_C_B.tum cvs_T_C_B.tum`, adding "
        "evo's own -a/-s if wanted; vicon_T_Cm_Bm and cvs_T_C_B differ by transforms on both "
        "sides, which evo's one-sided alignment cannot remove.",
    )
    et.add_argument("results", help="results/<session> folder or its pairs.parquet")
    et.add_argument("--out-dir", required=True, help="output folder")
    et.add_argument("--se3", help="se3 result.yaml with the mountings "
                    "(default: RESULTS/se3/calib/result.yaml if present)")
    et.set_defaults(func=cmd_export_trajectory)

    r = sub.add_parser(
        "run",
        help="run the workflow (snakemake with the workstation profile); other options pass through",
        description="Runs `python -m snakemake --profile profiles/default [ARGS]` (or "
        "workflow/profiles/default if the former is absent) in the current folder; every "
        "argument goes to snakemake unchanged, e.g. `cvsflow run --configfile my.yaml -n`.",
    )
    r.set_defaults(func=None)

    i = sub.add_parser(
        "init",
        help="write a session config from a recording folder, for you to check",
        description="Finds the stills folder, the video and the Nexus CSV / C3D export; lists "
        "the subjects and marker names in the export; tries common inner-corner sizes on the "
        "first stills; leaves TODO where it cannot know (square_m always) and layout_m out "
        "(learned from the take). Never overwrites. The file merges with config/config.yaml "
        "when given to --configfile.",
    )
    i.add_argument("dir", help="recording folder")
    i.add_argument("--out", help="config file to write (default DIR/cvsflow_session.yaml)")
    i.add_argument("--name", help="session name (default: the folder's name)")
    i.set_defaults(func=cmd_init)
    _add_handeye_parser(sub)
    return p


def main(argv=None) -> int:
    """Entry point of the ``cvsflow`` command; returns the exit code.

    Parameters
    ----------
    argv : list of str, optional
        The arguments after the program name; default ``sys.argv[1:]``.

    Returns
    -------
    int
        0 on success, 1 on a :class:`CvsflowError` (one line ``cvsflow: error: ...`` on
        stderr), snakemake's code for ``run``; usage errors exit 2 through argparse.
    """
    argv = list(sys.argv[1:] if argv is None else argv)
    # `run` passes everything after it to snakemake, unparsed.
    if "run" in argv and all(a.startswith("-") for a in argv[: argv.index("run")]):
        k = argv.index("run")
        extra = argv[k + 1 :]
        if extra in (["-h"], ["--help"]):
            build_parser().parse_args(["run", "--help"])
        args = build_parser().parse_args(argv[: k + 1])
        logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
        try:
            return cmd_run(args, extra)
        except CvsflowError as exc:
            print(f"cvsflow: error: {exc}", file=sys.stderr)
            return 1
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(message)s")
    try:
        return args.func(args)
    except CvsflowError as exc:
        print(f"cvsflow: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
