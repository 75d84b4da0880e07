"""``cvsflow handeye``: hand-eye calibration from stills, timestamped frames or a camera pose stream.

The frames and the carrier's pose stream may come from a ROS bag (``--bag`` with
``--image-topic`` and ``--pose-topic``): the same images and poses as a frame folder and a pose
file hold (:mod:`cvsflow.io.rosbag_images`, :mod:`cvsflow.io.rosbag_poses`), the same result.
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np

from cvsflow.cli.args import EPILOG, add_board_args, board_from_args
from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)


def _hand_eye_options(args) -> dict:
    """The fit options the stills and frames modes share."""
    return {
        "mode": "eye_to_hand" if args.eye_to_hand else "eye_in_hand", "method": args.method,
        "free_intrinsics": [n.strip() for n in args.free_intrinsics.split(",") if n.strip()],
        "pose_noise": not args.exact_poses,
        "pose_sigma_m": None if args.pose_sigma_mm is None else 1e-3 * args.pose_sigma_mm,
        "pose_sigma_rad": None if args.pose_sigma_deg is None else np.radians(args.pose_sigma_deg),
        "subpix_window_px": args.subpix_window_px,
    }  # fmt: skip


def _stream_format(args, option="--pose-format"):
    """The pose-stream format a ``--pose-format`` names (a stream's, or auto)."""
    fmt = args.pose_format
    if fmt not in ("auto", "tum", "asl", "eth"):
        raise InputError(f"{option} {fmt}: the frames and camera-poses modes take a time-stamped pose "
                         "stream (asl, tum, eth or auto); visp and csv are pose lists for --stills")
    return fmt


def _bag_time(args) -> str:
    """The bag's time source: header stamps, or receive times with ``--receive-time``."""
    return "receive" if args.receive_time else "header"


def _carrier_stream(args):
    """The carrier's pose stream: ``--pose-topic`` of ``--bag``, else the ``--poses`` file."""
    if args.pose_topic is not None:
        from cvsflow.io.rosbag_poses import read_bag_pose_stream

        return read_bag_pose_stream(args.bag, args.pose_topic, args.pose_parent, args.pose_child,
                                    _bag_time(args))
    from cvsflow.io.mocap.formats import read_pose_stream

    return read_pose_stream(args.poses, _stream_format(args), given_by="--pose-format")


def _check_sources(args) -> None:
    """One carrier pose source, the bag options only with a bag; a named InputError otherwise."""
    if args.bag is None:
        given = [o for o, v in (("--image-topic", args.image_topic), ("--pose-topic", args.pose_topic),
                                ("--pose-parent", args.pose_parent), ("--pose-child", args.pose_child),
                                ("--camera-pose-topic", args.camera_pose_topic))
                 if v is not None]  # fmt: skip
        if given:
            raise InputError(f"{', '.join(given)}: topics and frames of a ROS bag; expected --bag BAG "
                             "with them")
    elif (args.image_topic is None) == (args.camera_pose_topic is None):
        raise InputError(f"--bag {args.bag}: expected --image-topic (the camera's Image or CompressedImage "
                         "topic) or --camera-pose-topic (the camera's pose in the target frame), one of "
                         "them; `cvsflow init BAG` lists the topics")  # fmt: skip
    if args.poses is not None and args.pose_topic is not None:
        raise InputError("--poses and --pose-topic: expected one source of the carrier's poses")
    if args.poses is None and args.pose_topic is None:
        raise InputError("--poses: the carrier's poses are required (a pose file or stream; with --bag, "
                         "--pose-topic instead)")  # fmt: skip


def _camera_poses_mode(args) -> bool:
    """Whether the camera's own pose stream is given (a file, or a topic of the bag)."""
    return args.camera_poses is not None or args.camera_pose_topic is not None


def _handeye_stills(args, board) -> dict:
    """Stills with one carrier pose each (paired by name, number or position)."""
    from cvsflow.handeye import calibrate_hand_eye, pair_stills_with_poses
    from cvsflow.io.files import read_yaml
    from cvsflow.io.media import list_stills, read_gray
    from cvsflow.io.poses import natural_key, pose_table_T, read_pose_list
    from cvsflow.io.visp import read_known_camera

    if args.camera is None:
        raise InputError("--camera: the stills mode needs known intrinsics (a camera file)")
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
    images = [(p.name, read_gray(p)) for p in paths]
    res = calibrate_hand_eye(images, T_W_X, board, read_known_camera(args.camera), pose_names=origins,
                             **_hand_eye_options(args))  # fmt: skip
    return {"input": "stills", "stills_dir": str(args.stills), "camera": str(args.camera),
            "poses": str(args.poses), "pose_format": args.pose_format, "pairing": rule, **res}  # fmt: skip


def _folder_frames(args):
    """A frame folder's images (named by their files), exact times, undecodable names, record."""
    from cvsflow.io.frames import frame_list, read_frame_gray

    frames = frame_list(args.frames)
    images, t_ns, bad = [], [], []
    for path, t in zip(frames["path"], frames["t_ns"], strict=True):
        gray = read_frame_gray(path)
        if gray is None:
            bad.append(path.name)
            continue
        images.append((path.name, gray))
        t_ns.append(int(t))
    return images, t_ns, bad, {"frames_dir": str(args.frames), "frames_layout": frames.attrs["layout"]}


def _bag_frames(args):
    """A bag image topic's frames (named by their time in ns, as a folder's files), as _folder_frames."""
    from cvsflow.io.rosbag_images import iter_bag_images

    images, t_ns, bad = [], [], []
    for k, t, gray in iter_bag_images(args.bag, args.image_topic, "gray", _bag_time(args),
                                      undecodable=True):
        if gray is None:
            bad.append(f"message {k}")
            continue
        images.append((str(t), gray))
        t_ns.append(int(t))
    record = {"bag": str(args.bag), "image_topic": args.image_topic, "bag_time": _bag_time(args)}
    return images, t_ns, bad, record


def _handeye_frames(args, board) -> dict:
    """Timestamped frames and the carrier's pose stream (intrinsics from the frames without --camera)."""
    from cvsflow.calibration import calibrate_camera
    from cvsflow.handeye import calibrate_from_frames
    from cvsflow.io.mocap.streams import stream_T
    from cvsflow.io.visp import read_known_camera

    images, t_ns, bad, source = _bag_frames(args) if args.bag is not None else _folder_frames(args)
    if bad:
        log.warning("%s: %d frames cannot be decoded or are cut short (truncated?), left out: %s",
                    args.bag or args.frames, len(bad), ", ".join(bad[:10]))  # fmt: skip
    stream = _carrier_stream(args)
    if args.camera is not None:
        camera, calibration = read_known_camera(args.camera), {"source": str(args.camera)}
    else:
        camera, _ = calibrate_camera(images, board)
        calibration = {"source": "calibrated from the same frames", "rms_px": camera["rms_px"],
                       "n_used": camera["n_used"], "std": camera["std"], "warnings": camera["warnings"]}
        for w in camera["warnings"]:
            log.warning("intrinsics from the frames: %s", w)
    res = calibrate_from_frames(images, np.asarray(t_ns, np.int64), stream["t_ns"].to_numpy(),
                                stream_T(stream), board, camera, dt_offset_s=args.dt_offset_s,
                                max_frames=args.max_frames, **_hand_eye_options(args))  # fmt: skip
    res["intrinsics"]["calibration"] = calibration
    return {"input": "bag" if args.bag is not None else "frames", **source, "frames_undecodable": bad,
            "poses": stream.attrs.get("path", str(args.poses)), "pose_stream": _stream_info(stream), **res}


def _stream_info(stream) -> dict:
    """What a pose stream was read as (handeye.yaml)."""
    keys = ("path", "format", "time_unit", "n_rows_file", "n_duplicates_dropped", "n_quats_renormalised")
    return {k: stream.attrs.get(k) for k in keys}


def _handeye_camera_poses(args) -> dict:
    """The camera's pose stream in the target frame and its marker body's: offset, mountings."""
    from cvsflow.handeye import (
        StreamsOptions,
        estimate_streams,
        inflate,
        split_half_check,
        split_half_inflation,
        streams_record,
    )
    from cvsflow.io.mocap.formats import read_pose_stream
    from cvsflow.io.mocap.streams import stream_T

    if args.eye_to_hand:
        raise InputError("--camera-poses with --eye-to-hand: a camera's pose stream is fitted eye-in-hand "
                         "(the camera on its marker body, the target fixed)")  # fmt: skip
    if args.camera_pose_topic is not None:
        from cvsflow.io.rosbag_poses import read_bag_pose_stream

        cam = read_bag_pose_stream(args.bag, args.camera_pose_topic, time=_bag_time(args))
    else:
        cam = read_pose_stream(args.camera_poses, args.camera_pose_format, given_by="--camera-pose-format")
    moc = _carrier_stream(args)
    streams = (cam["t_ns"].to_numpy(), stream_T(cam), moc["t_ns"].to_numpy(), stream_T(moc))
    options = StreamsOptions(estimate_dt=args.dt_offset_s is None, dt_init_s=args.dt_offset_s)
    res = estimate_streams(*streams, options)
    for what in ("dt", "hand_eye"):
        if not res.observability[what]["observable"] and res.observability[what]["reason"]:
            log.warning("%s not determined: %s", "dt_offset_s" if what == "dt" else "T_Cm_C",
                        res.observability[what]["reason"])  # fmt: skip
    split = None
    if not args.no_split_half and res.T_Cm_C is not None:
        split = split_half_check(*streams, options)
        factor = split_half_inflation(split)
        if factor > 1.0:
            log.warning("split-half check: the two halves of the recording disagree beyond their stated "
                        "errors (mean z^2 %.2f > %.2f, %d of %d components within 2 std): the standard "
                        "errors are widened by sqrt(mean z^2) = %.2f", split["mean_z2"],
                        split["mean_z2_limit"], split["n_agree"], split["n"], factor)  # fmt: skip
            res = inflate(res, factor)
    return {"input": "camera_poses", "camera_poses": _stream_info(cam), "poses": _stream_info(moc),
            **streams_record(res, split)}  # fmt: skip


def cmd_handeye(args) -> int:
    """``cvsflow handeye``: hand-eye calibration from stills, timestamped frames or a camera pose stream.

    Writes ``OUT/handeye.yaml`` (and for stills or frames ``OUT/handeye_views.png``, the
    mocap-chain reprojection per view in the fit and left out) and prints ``T_Cm_C``
    (eye-in-hand) or ``T_W_C`` (eye-to-hand) with its standard errors (mm, deg), and the time
    offset where one was estimated.

    - ``--stills``: one carrier pose each (:func:`cvsflow.handeye.stills.calibrate_hand_eye`).
    - ``--frames``: a timestamped frame folder and the carrier's pose stream
      (:func:`cvsflow.handeye.frame_stream.calibrate_from_frames`); intrinsics from the same
      frames when no ``--camera`` is given.
    - ``--bag``: the same from a ROS bag's image topic and the carrier's pose topic (or
      ``--poses``), named frames by their time in ns; with ``--camera-pose-topic`` instead of
      ``--image-topic``, the camera-poses mode on the bag's two pose topics.
    - ``--camera-poses``: the camera's pose stream in the target frame and its marker body's
      (:func:`cvsflow.handeye.stream_fit.estimate_streams`, with the split-half check).

    Parameters
    ----------
    args : argparse.Namespace
        ``stills`` | ``frames`` | ``bag`` | ``camera_poses``, ``poses`` (file or glob; None with
        ``pose_topic``), ``image_topic`` or ``camera_pose_topic``, ``pose_topic``, ``pose_parent``,
        ``pose_child`` and
        ``receive_time`` (with ``bag``), ``pose_format``,
        ``camera_pose_format``, ``csv_spec``, ``inner`` with ``square_m`` (m) or ``target`` (a
        Kalibr target file), ``camera`` (known intrinsics file), ``out``, ``force`` (replace an
        ``OUT/handeye.yaml``), ``eye_to_hand``,
        ``method``, ``free_intrinsics`` (comma separated), ``exact_poses``, ``pose_sigma_mm``,
        ``pose_sigma_deg``, ``subpix_window_px``, ``dt_offset_s``, ``max_frames``,
        ``no_split_half``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No images or frames, unreadable poses, camera or target file, stills and poses that
        cannot be paired, a missing board or ``--square-m``, a pose list where a stream is
        needed, an ``OUT/handeye.yaml`` without ``--force``; no ``--poses`` (nor ``--pose-topic``
        with ``--bag``), both, bag options without ``--bag``, ``--bag`` without ``--image-topic``.
    BagError, TopicNotFoundError, TopicTypeError, ImageDecodeError, ZeroStampError, FrameIdError
        The bag, a topic, an image or a pose frame (:mod:`cvsflow.io.rosbag`).
    ConfigError
        A target file of an unsupported type, or with a missing or invalid key.
    CalibrationError
        Too few usable stills or motions, or the fit failed.
    ImplausibleError
        Poses paired wrong or at the wrong scale (:mod:`cvsflow.handeye.consistency`); a pose
        stream that does not overlap the frames (both spans named).
    """
    import cv2

    from cvsflow.io.files import refuse_overwrite, save_figure, write_yaml
    from cvsflow.plots.chain_reprojection import plot_chain_reprojection

    out = Path(args.out) / "handeye.yaml"
    fig_path = Path(args.out) / "handeye_views.png"
    _check_sources(args)
    written = [out] if _camera_poses_mode(args) else [out, fig_path]
    refuse_overwrite(written, args.force, "cvsflow handeye")
    cv2.setNumThreads(1)
    if _camera_poses_mode(args):
        res = _handeye_camera_poses(args)
    else:
        if args.inner is None and args.target is None:
            raise InputError("the board: give --inner NXxNY with --square-m, or --target FILE (a Kalibr "
                             "target file), for --stills, --frames and --bag")  # fmt: skip
        board = board_from_args(args)
        res = _handeye_stills(args, board) if args.stills is not None else _handeye_frames(args, board)
    write_yaml({"command": "cvsflow handeye", **res}, out)
    _print_summary(res, "T_W_C" if args.eye_to_hand else "T_Cm_C")
    print(f"wrote {out}")
    if any("chain_rms_px" in s for s in res.get("stills", [])):  # per view, in the fit and left out
        save_figure(plot_chain_reprojection(res["stills"]), fig_path)
        print(f"wrote {fig_path}")
    return 0


def _print_summary(res, name) -> None:
    """The hand-eye transform, its standard errors and the offset, on the console."""
    if res.get(name) is None:
        print(f"{name}: not determined: {res['observability']['hand_eye']['reason']}")
    else:
        T, sd = np.asarray(res[name]), res["std"][name]
        used = (f"; {res['n_used']} of {res['n_stills']} views, RMS {res['rms_px']:.3f} px" if "n_used" in res
                else f"; {res['counts']['n_used']} of {res['counts']['n_camera']} camera poses")  # fmt: skip
        print(f"{name}: t = [{', '.join(f'{v:.5f}' for v in T[:3, 3])}] m (+- {sd['x_mm']:.2f}, "
              f"{sd['y_mm']:.2f}, {sd['z_mm']:.2f} mm), rotation +- {sd['rotation_deg']:.3f} deg{used}")
    if "dt_offset_s" in res:
        if res["dt_offset_s"] is not None:
            print(f"dt_offset_s = {res['dt_offset_s']:.5f} s +- {1e3 * res['dt_offset_std_s']:.2f} ms "
                  "(t_poses = t_camera + dt)")  # fmt: skip
        else:
            print(f"dt_offset_s: not determined ({res['observability']['dt']['reason']}); the fit used "
                  f"{res['dt_used_s']:g} s")  # fmt: skip
    if res.get("split_half"):
        sh = res["split_half"]
        print(f"split-half check: {sh['n_agree']} of {sh['n']} components within 2 std, mean z^2 "
              f"{sh['mean_z2']:.2f} (honest errors: below {sh['mean_z2_limit']:.2f} in 95 % of cases)")


def _add_handeye_parser(sub) -> None:
    h = sub.add_parser(
        "handeye",
        help="hand-eye calibration (T_Cm_C, T_W_B) from stills, timestamped frames or a camera pose stream",
        description="The camera's mounting on its carrier (robot end-effector or marker body) and the "
        "target in the carrier's world, from: --stills of a board, each with a carrier pose; "
        "--frames, a timestamped frame folder (ASL cam0/ or images named by ns) with the "
        "carrier's pose stream (each frame's pose interpolated at its time; intrinsics from the "
        "same frames without --camera); or --camera-poses, the camera's pose in the target "
        "frame per timestamp with its marker body's stream (time offset, mountings and honest "
        "standard errors, with a split-half check). Eye-in-hand (default: camera on the carrier, "
        "board fixed) gives T_Cm_C and T_W_B; --eye-to-hand (board on the carrier, camera fixed) "
        "gives T_W_C and T_Bm_B. Writes OUT/handeye.yaml.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    what = h.add_mutually_exclusive_group(required=True)
    what.add_argument("--stills", help="folder of stills (png, jpg, ...), one carrier pose each")
    what.add_argument("--frames", help="timestamped frame folder: ASL cam0/ (data.csv + data/) or images "
                      "named by integer ns")  # fmt: skip
    what.add_argument("--bag", help="a ROS bag (ROS 1 .bag, ROS 2 folder, .db3 or .mcap): the frames of "
                      "--image-topic (header stamps) with the carrier's --pose-topic, as --frames and "
                      "--poses take them from files")  # fmt: skip
    what.add_argument("--camera-poses", metavar="FILE", help="the camera's pose in the target frame per "
                      "timestamp (a pose stream: asl, tum or eth), as a detector writes it")  # fmt: skip
    h.add_argument("--poses", help="the carrier's poses: pose file(s) for --stills (a quoted glob for one "
                   "file per still), a pose stream for --frames and --camera-poses (required, but for "
                   "--bag with --pose-topic)")  # fmt: skip
    h.add_argument("--image-topic", help="--bag: the camera's sensor_msgs Image or CompressedImage topic")
    h.add_argument("--camera-pose-topic", help="--bag, instead of --image-topic: the camera's pose in the "
                   "target frame per message (PoseStamped, TransformStamped, Odometry), as --camera-poses "
                   "takes it from a file")  # fmt: skip
    h.add_argument("--pose-topic", help="--bag: the carrier's poses (PoseStamped, TransformStamped, "
                   "Odometry, or /tf with --pose-parent and --pose-child)")  # fmt: skip
    h.add_argument("--pose-parent", help="--pose-topic: the frame the poses are in (header.frame_id; "
                   "required for /tf)")  # fmt: skip
    h.add_argument("--pose-child", help="--pose-topic: the frame whose pose it is (child_frame_id; required "
                   "for /tf)")  # fmt: skip
    h.add_argument("--receive-time", action="store_true", help="--bag: frame and pose times from the bag's "
                   "receive times (transport delay included), for publishers that leave their header "
                   "stamps at zero; default the header stamps")  # fmt: skip
    h.add_argument("--pose-format", choices=("visp", "tum", "asl", "eth", "csv", "auto"), default="auto",
                   help="visp: vpPoseVector YAML (m, theta-u rad); tum: t tx ty tz qx qy qz qw (s); "
                   "asl: ASL/EuRoC CSV, a header naming the columns (timestamp [ns], x, y, z, qx, "
                   "qy, qz, qw, any order); eth: t, x, y, z, qx, qy, qz, qw (s, comma separated); "
                   "csv: columns and units in --csv-spec; auto (default): from the file")  # fmt: skip
    h.add_argument("--camera-pose-format", choices=("tum", "asl", "eth", "auto"), default="auto",
                   help="format of --camera-poses (default: from the file)")
    h.add_argument("--csv-spec", help="YAML of the CSV's columns and units (time_col, pos_cols, "
                   "pos_unit, rot, rot_cols, angle_unit, name_col)")  # fmt: skip
    add_board_args(h, required=False)
    h.add_argument("--camera", help="known intrinsics: ViSP camera XML, cvsflow camera.yaml or OpenCV "
                   "YAML (required with --stills; with --frames, calibrated from the frames when absent)")
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
    h.add_argument("--dt-offset-s", type=float, help="--frames, --camera-poses: hold the clock offset at "
                   "this value (t_poses = t_camera + dt, s) instead of estimating it")  # fmt: skip
    h.add_argument("--max-frames", type=int, default=100, help="--frames: most frames the fit takes, "
                   "spread evenly in time (default 100)")  # fmt: skip
    h.add_argument("--no-split-half", action="store_true",
                   help="--camera-poses: skip the split-half check (two more fits)")
    h.set_defaults(func=cmd_handeye)
