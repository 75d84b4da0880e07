"""The ``cvsflow`` command: calibrate stills, export results, run the workflow, start a session.

One module per subcommand group (``calibrate``, ``rig`` (calibrate-rig), ``export``, ``run``,
``demo``, ``init``, ``remux``, ``handeye``); this one builds the parser and dispatches (``main``, the
``cvsflow`` entry point).

Exit codes: 0 success; 1 a cvsflow error (one line on stderr naming the file); 2 a usage error
(argparse); any other code from ``cvsflow run`` is snakemake's own.
"""

from __future__ import annotations

import argparse
import logging
import sys

from cvsflow.cli.args import EPILOG, add_board_args
from cvsflow.cli.calibrate import cmd_calibrate
from cvsflow.cli.demo import MIN_DURATION_S, cmd_demo, duration_arg
from cvsflow.cli.export import cmd_export_camera, cmd_export_trajectory
from cvsflow.cli.handeye import _add_handeye_parser
from cvsflow.cli.init import cmd_init
from cvsflow.cli.remux import cmd_remux
from cvsflow.cli.rig import cmd_calibrate_rig
from cvsflow.cli.run import cmd_run
from cvsflow.exceptions import CvsflowError


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of the ``cvsflow`` command and its subcommands.

    Returns
    -------
    argparse.ArgumentParser
        Subcommands ``calibrate``, ``calibrate-rig``, ``export camera``, ``export trajectory``, ``run``,
        ``demo``, ``init``, ``remux``, ``handeye``; each sets ``func`` to its ``cmd_*`` handler
        (None for ``run``, which :func:`main` handles).
    """
    p = argparse.ArgumentParser(
        prog="cvsflow",
        description="Camera + target pose accuracy against motion capture: calibrate, export, run, init.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("-v", "--verbose", action="store_true", help="log progress (INFO) on stderr")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    _add_calibrate_parsers(sub)
    _add_export_parsers(sub)
    _add_run_parsers(sub)
    _add_init_parser(sub)
    _add_remux_parser(sub)
    _add_handeye_parser(sub)
    return p


def _add_calibrate_parsers(sub) -> None:
    """Add ``calibrate`` and ``calibrate-rig`` to the subcommands ``sub``."""
    c = sub.add_parser(
        "calibrate",
        help="calibrate a camera from a folder of chessboard, ChArUco or AprilGrid stills",
        description="Calibrate from stills alone (the workflow's calibrate stage); writes "
        "camera.yaml, calib_corners.parquet and the OpenCV, Kalibr and ROS files into OUT.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    c.add_argument("dir", help="folder of stills (png, jpg, ...)")
    add_board_args(c, charuco=True)
    c.add_argument("--marker-m", type=float, help="ChArUco marker side, metres")
    c.add_argument("--dictionary", help="ChArUco ArUco dictionary, e.g. DICT_5X5_100")
    c.add_argument("--out", required=True, help="output folder")
    c.add_argument("--force", action="store_true",
                   help="replace files of the same names in OUT (never otherwise)")
    c.add_argument("--subpix-window-px", type=int, default=None,
                   help="one cornerSubPix half window for every corner (px; 11 = OpenCV's sample); "
                   "default: each corner its own, sized to its squares")
    c.add_argument("--min-images", type=int, default=5, help="fewest stills with a board")
    c.add_argument("--model", choices=("opencv5", "opencv8", "fisheye4"), default="opencv5",
                   help="lens model: OpenCV's 5 terms (default), the 8-term rational model, the "
                   "4-term fisheye (Kannala-Brandt); camera.yaml's cross_validation says whether a "
                   "richer one is needed")
    c.add_argument("--no-outlier-rejection", action="store_true",
                   help="fit every corner (those beyond 4 sigma are still named in camera.yaml)")
    c.set_defaults(func=cmd_calibrate)

    cr = sub.add_parser(
        "calibrate-rig",
        help="calibrate two or more fixed cameras and their relative poses",
        description="Each camera from its folder of stills, then every camera's pose from camera "
        "0 from the stills they took together (the same file name in each folder); writes "
        "cam<i>/ (as calibrate), rig.yaml (T_Ci_C0 with standard errors) and a Kalibr camchain.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    cr.add_argument("dirs", nargs="+", help="one stills folder per camera, camera 0 first")
    add_board_args(cr)
    cr.add_argument("--out", required=True, help="output folder")
    cr.add_argument("--force", action="store_true",
                    help="replace files of the same names in OUT (never otherwise)")
    cr.add_argument("--subpix-window-px", type=int, default=None,
                    help="one cornerSubPix half window for every corner (px); default: per corner")
    cr.add_argument("--min-images", type=int, default=5, help="fewest stills with a board per camera")
    cr.add_argument("--min-shared-views", type=int, default=3,
                    help="fewest stills each camera must share with camera 0")
    cr.set_defaults(func=cmd_calibrate_rig)


def _add_export_parsers(sub) -> None:
    """Add ``export camera`` and ``export trajectory`` to the subcommands ``sub``."""
    e = sub.add_parser("export", help="export a finished run's camera or trajectories")
    esub = e.add_subparsers(dest="what", required=True, metavar="WHAT")
    ec = esub.add_parser(
        "camera",
        help="camera.yaml as OpenCV FileStorage, Kalibr camchain or ROS camera_info",
        description="Kalibr's radtan model has no k3: it is dropped; the largest pixel shift "
        "that causes is written in the file and warned about above 0.1 px.",
    )
    ec.add_argument("src", help="results/<session> folder or a camera.yaml")
    ec.add_argument("--format", choices=("opencv", "kalibr", "ros", "mrcal"), required=True)
    ec.add_argument("--out", required=True, help="output file")
    ec.add_argument("--force", action="store_true", help="replace OUT if it exists (never otherwise)")
    ec.set_defaults(func=cmd_export_camera)
    et = esub.add_parser(
        "trajectory",
        help="a session's or a flight's trajectories as TUM, EuRoC/ASL or KITTI files, for evo",
        description="A session (results/<session>): from pairs.parquet, on the video clock (m, "
        "quaternion xyzw), unaligned: cvs_T_C_B (PnP), vicon_T_Cm_Bm (the Vicon, marker bodies) "
        "and, when the session has an se3 result, vicon_T_C_B = T_Cm_C^-1 T_Cm_Bm T_Bm_B (the "
        "Vicon in the CVS frames). Compare with `evo_ape tum vicon_T_C_B.tum cvs_T_C_B.tum`, "
        "adding evo's own -a/-s if wanted; vicon_T_Cm_Bm and cvs_T_C_B differ by transforms on "
        "both sides, which evo's one-sided alignment cannot remove. A flight "
        "(results/flights/<flight>): its reference_aligned, onboard_aligned and "
        "onboard_unaligned trajectories in the format asked. Times are exact nanoseconds in "
        "every format (TUM and KITTI's times file: seconds with 9 decimals; asl: integer ns).",
    )
    et.add_argument("results", help="results/<session> folder or its pairs.parquet, or "
                    "results/flights/<flight>")
    et.add_argument("--out-dir", required=True, help="output folder")
    et.add_argument("--format", choices=("tum", "asl", "kitti"), default="tum",
                    help="tum (.tum), asl (EuRoC/ASL CSV, .csv; evo's euroc) or kitti (.kitti and "
                    ".times.txt); default tum")
    et.add_argument("--force", action="store_true",
                    help="replace files of the names it writes in OUT_DIR (never otherwise)")
    et.add_argument("--se3", help="se3 result.yaml with the mountings "
                    "(default: RESULTS/se3/calib/result.yaml if present)")
    et.set_defaults(func=cmd_export_trajectory)


def _add_run_parsers(sub) -> None:
    """Add ``run`` (handled by :func:`main`) and ``demo`` to the subcommands ``sub``."""
    r = sub.add_parser(
        "run",
        usage="cvsflow run [CONFIG.yaml] [--cores N] [snakemake options] [targets]",
        help="run the workflow on a config file, from any folder; snakemake options pass through",
        description="Runs the workflow that ships in the package on exactly the sessions and "
        "flights of CONFIG.yaml (keys left out take the schema's defaults), with results/, "
        "logs/ and benchmarks/ in the current folder (or --directory DIR), using the package's "
        "workstation profile (--workflow-profile slurm: its SLURM profile). Paths in the config "
        "are relative to that folder. Every other argument goes to snakemake unchanged, e.g. "
        "`cvsflow run my.yaml -n`. Without CONFIG it runs the Snakefile of the current folder "
        "(in the repository: the demo, as `snakemake --cores 2`). A config may run code "
        "(`__use_yte__: true`, Snakemake's YTE templates): read one from elsewhere first.",
    )
    r.set_defaults(func=None)

    d = sub.add_parser(
        "demo",
        help="render the demo session into a folder and run the workflow on it there",
        description="Writes the demo's config as DIR/session.yaml (a rendered session and a "
        "rendered flight, every key commented) and runs it in DIR: the workflow renders the "
        "inputs into DIR/data/ and writes DIR/results/, DIR/logs/, DIR/benchmarks/. A second "
        "call with the same options has nothing to do; an existing session.yaml that differs "
        "is never overwritten. About 2-4 minutes on 2 cores at the default 20 s.",
    )
    d.add_argument("dir", help="the demo's folder (created if needed)")
    d.add_argument("--duration-s", type=duration_arg, help="seconds of rendered video "
                   f"(default the demo's 20; at least {MIN_DURATION_S:g})")
    d.add_argument("--cores", type=int, help="cores to use (default the workstation profile's, 2)")
    d.set_defaults(func=cmd_demo)


def _add_init_parser(sub) -> None:
    """Add ``init`` to the subcommands ``sub``."""
    i = sub.add_parser(
        "init",
        help="write a session config from a recording folder or a ROS bag, for you to check",
        description="Finds the stills folder, the video and the Nexus CSV / C3D export; lists "
        "the subjects and marker names in the export; tries common inner-corner sizes on the "
        "first stills; leaves TODO where it cannot know (square_m always) and layout_m out "
        "(learned from the take). Never overwrites. Run it with `cvsflow run FILE`. Two or more "
        "camera folders (DIR/<camera>/ with its stills "
        "and one video; shared views in DIR/<camera>/shared/ or DIR/shared/<camera>/, the same "
        "file names in every camera) give a rig session (a cameras: list). A ROS bag (ROS 1 .bag, "
        "ROS 2 folder, .db3 or .mcap) instead: lists its topics (type, count, rate) and writes a "
        "session whose bag block names the likely image topic and the camera and board bodies' "
        "pose topics or TF frames, TODO where the bag cannot tell.",
    )
    i.add_argument("dir", help="recording folder, a ROS bag, or a camera-pose stream (CSV)")
    i.add_argument("--out", help="config file to write (default DIR/cvsflow_session.yaml; for a bag "
                   "BAG_session.yaml beside it)")  # fmt: skip
    i.add_argument("--name", help="session name (default: the folder's or the bag's name)")
    lay = i.add_mutually_exclusive_group()
    lay.add_argument("--rig", dest="layout", action="store_const", const="rig",
                     help="a rig session, or an error saying what the camera folders lack")
    lay.add_argument("--mono", dest="layout", action="store_const", const="mono",
                     help="one camera, even if the subfolders look like a rig")
    i.set_defaults(func=cmd_init, layout="auto")


def _add_remux_parser(sub) -> None:
    """Add ``remux`` to the subcommands ``sub``."""
    m = sub.add_parser(
        "remux",
        help="give a raw H.264/HEVC stream (Raspberry Pi cameras) its frame times in an MP4",
        description="A raw stream's frames carry no timestamps, which the pipeline needs. Copies "
        "its packets (no re-encoding) into a new MP4 with the camera's timestamps (--timestamps: "
        "a timecode format v2 file, as `libcamera-vid --save-pts` / `rpicam-vid --save-pts` "
        "write) or, failing those, a nominal frame rate (--fps). Never overwrites.",
    )
    m.add_argument("src", help="the raw stream (.h264, .hevc, ...)")
    m.add_argument("--out", required=True, help="MP4 to write (a new file)")
    times = m.add_mutually_exclusive_group(required=True)
    times.add_argument("--timestamps", help="timecode format v2 file, one time in ms per frame")
    times.add_argument("--fps", type=float, help="nominal frame rate, frames/s")
    m.set_defaults(func=cmd_remux)


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

