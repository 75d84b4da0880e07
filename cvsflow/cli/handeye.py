"""``cvsflow handeye``: hand-eye calibration from stills with one carrier pose each."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from cvsflow.cli.args import EPILOG, add_board_args, board_from_args
from cvsflow.exceptions import ConfigError, InputError

log = logging.getLogger(__name__)


def cmd_handeye(args) -> int:
    """``cvsflow handeye``: hand-eye calibration from stills with one carrier pose each.

    Writes ``OUT/handeye.yaml`` (the result of :func:`cvsflow.handeye.stills.calibrate_hand_eye`
    plus the command's inputs and the pairing rule) and prints ``T_Cm_C`` (eye-in-hand) or
    ``T_W_C`` (eye-to-hand) with its standard errors (mm, deg).

    Parameters
    ----------
    args : argparse.Namespace
        ``stills``, ``poses`` (file or glob), ``pose_format``, ``csv_spec``, ``inner`` with
        ``square_m`` (m) or ``target`` (a Kalibr checkerboard file), ``camera`` (known
        intrinsics file), ``out``, ``force`` (replace an ``OUT/handeye.yaml``), ``eye_to_hand``,
        ``method``, ``free_intrinsics`` (comma separated), ``exact_poses``,
        ``pose_sigma_mm``, ``pose_sigma_deg``, ``subpix_window_px``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No images, unreadable poses, camera or target file, stills and poses that cannot be
        paired, a missing ``--square-m``, an ``OUT/handeye.yaml`` without ``--force``.
    ConfigError
        A target file that is an AprilGrid (not taken here yet), of an unsupported type, or
        with a missing or invalid key.
    CalibrationError
        Too few usable stills or motions, or the fit failed.
    """
    import cv2

    from cvsflow.handeye import calibrate_hand_eye, pair_stills_with_poses
    from cvsflow.io.files import read_yaml, refuse_overwrite, write_yaml
    from cvsflow.io.media import list_stills, read_gray
    from cvsflow.io.poses import natural_key, pose_table_T, read_pose_list
    from cvsflow.io.visp import read_known_camera

    board = board_from_args(args)
    if board.get("type") == "aprilgrid":
        raise ConfigError(f"--target {args.target}: an AprilGrid; cvsflow handeye's stills take a "
                          "chessboard (whole views) so far: give a checkerboard target or --inner")
    out = Path(args.out) / "handeye.yaml"
    refuse_overwrite([out], args.force, "cvsflow handeye")
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
    h.add_argument("--pose-format", choices=("visp", "tum", "asl", "eth", "csv", "auto"), default="auto",
                   help="visp: vpPoseVector YAML (m, theta-u rad); tum: t tx ty tz qx qy qz qw (s); "
                   "asl: ASL/EuRoC CSV, a header naming the columns (timestamp [ns], x, y, z, qx, "
                   "qy, qz, qw, any order); eth: t, x, y, z, qx, qy, qz, qw (s, comma separated); "
                   "csv: columns and units in --csv-spec; auto (default): from the file")  # fmt: skip
    h.add_argument("--csv-spec", help="YAML of the CSV's columns and units (time_col, pos_cols, "
                   "pos_unit, rot, rot_cols, angle_unit, name_col)")  # fmt: skip
    add_board_args(h)
    h.add_argument("--camera", required=True,
                   help="known intrinsics: ViSP camera XML, cvsflow camera.yaml or OpenCV YAML")
    h.add_argument("--out", required=True, help="output folder")
    h.add_argument("--force", action="store_true", help="replace an OUT/handeye.yaml (never otherwise)")
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
