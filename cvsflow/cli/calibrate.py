"""``cvsflow calibrate``: calibrate a camera from a folder of chessboard, ChArUco or AprilGrid stills."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cvsflow.cli.args import board_from_args
from cvsflow.exceptions import InputError


def _board_from_args(args) -> dict:
    """The board config of ``--inner`` (a chessboard), ``--target`` (a Kalibr target file) or
    ``--charuco`` (with its marker)."""
    if getattr(args, "charuco", None) is None:
        return board_from_args(args)
    if args.square_m is None:
        raise InputError("--square-m: the square side in metres is needed with --charuco")
    missing = [f"--{k.replace('_', '-')}" for k in ("marker_m", "dictionary")
               if getattr(args, k, None) is None]
    if missing:
        raise InputError(f"--charuco {args.charuco[0]}x{args.charuco[1]}: also give "
                         f"{' and '.join(missing)} (e.g. --marker-m 0.06 --dictionary DICT_5X5_100)")
    from cvsflow.board import charuco_board

    board = {"type": "charuco", "squares_x": args.charuco[0], "squares_y": args.charuco[1],
             "square_m": float(args.square_m), "marker_m": float(args.marker_m),
             "dictionary": str(args.dictionary)}
    charuco_board(board)  # checks the marker size and the dictionary (ConfigError)
    return board


def cmd_calibrate(args) -> int:
    """``cvsflow calibrate``: calibrate a camera from a folder of chessboard stills.

    Writes ``camera.yaml``, ``calib_corners.parquet`` (docs/contracts.md), the
    projection-uncertainty map (``projection_uncertainty.png``) and the OpenCV, Kalibr, ROS and
    mrcal camera files its lens model allows into ``args.out``; prints the intrinsics (px), the
    RMS, the corners left out, the projection uncertainty, the quality verdicts and warnings,
    and why a format was not written.

    Parameters
    ----------
    args : argparse.Namespace
        ``dir`` (stills folder), ``inner`` ((nx, ny) inner corners of a chessboard),
        ``charuco`` ((sx, sy) squares, with ``marker_m`` (m) and ``dictionary``) or ``target``
        (a Kalibr target file: an AprilGrid or a checkerboard), ``square_m`` (square side, m;
        not with ``target``), ``out`` (output folder), ``force`` (replace files of the same
        names there), ``subpix_window_px`` (None: per corner),
        ``min_images``, ``model`` (``opencv5``, ``opencv8``, ``fisheye4``),
        ``no_outlier_rejection``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by :func:`main`).

    Raises
    ------
    InputError
        No images in ``dir``, ``--charuco`` without its marker, a missing ``--square-m`` or
        one given with ``--target``, an unreadable target file, or a file this command writes
        already in ``out`` without ``--force`` (checked before anything is computed). Stills
        that cannot be decoded are left out and named in camera.yaml.
    ConfigError
        A ChArUco marker not smaller than its square, an unknown dictionary, or a target file
        of an unsupported type or with a missing or invalid key.
    CalibrationError
        Too few stills with a board (or left after the outlier rejection), or the calibration
        failed.
    """
    import cv2

    from cvsflow.calibration import calibrate_camera, uncertainty_map_of
    from cvsflow.io.camera_formats import FORMAT_FILES, write_all_formats
    from cvsflow.io.files import refuse_overwrite, save_figure, write_parquet, write_yaml
    from cvsflow.io.media import list_stills, read_stills
    from cvsflow.plots.camera import plot_projection_uncertainty

    board = _board_from_args(args)
    out = Path(args.out)
    refuse_overwrite([out / n for n in ("camera.yaml", "calib_corners.parquet",
                                        "projection_uncertainty.png", *FORMAT_FILES.values())],
                     args.force, "cvsflow calibrate")
    cv2.setNumThreads(1)
    paths = list_stills(args.dir)
    if not paths:
        raise InputError(f"{args.dir}: no images (png, jpg, ...) in the stills folder")
    images, unreadable = read_stills(paths)
    camera, corners = calibrate_camera(
        images, board, subpix_window_px=args.subpix_window_px, min_images=args.min_images,
        unreadable=unreadable,
        model=args.model, reject_outliers=not args.no_outlier_rejection,
    )
    write_yaml(camera, out / "camera.yaml")
    write_parquet(corners, out / "calib_corners.parquet")
    files = write_all_formats(camera, out)
    maps = [uncertainty_map_of(camera, corners, d)
            for d in (camera["projection_uncertainty"]["distance_m"], float("inf"))]
    figure = out / "projection_uncertainty.png"
    save_figure(plot_projection_uncertainty(maps, camera), figure)
    print(_summary_line(camera, len(paths)))
    print(f"quality: {camera['quality']['summary']}")
    for text in camera["warnings"]:
        print(f"warning: {text}")
    written = [str(p) for p in files.values() if isinstance(p, Path)]
    print(f"wrote {out / 'camera.yaml'}, {figure}, " + ", ".join(written))
    for reason in (r for r in files.values() if not isinstance(r, Path)):
        print(reason)
    return 0


def _summary_line(camera: dict, n_stills: int) -> str:
    """The CLI's one-line summary: intrinsics, RMS, corners left out, projection uncertainty."""
    K = np.asarray(camera["K"])
    out = camera["outliers"]
    inf = camera["projection_uncertainty"]["at_infinity"]
    named = [s["name"] for s in out["named_stills"]]
    return (
        f"calibrated on {camera['n_used']} of {n_stills} stills ({camera['model']}): "
        f"fx {K[0, 0]:.5f} fy {K[1, 1]:.5f} cx {K[0, 2]:.5f} cy {K[1, 2]:.5f} px, RMS "
        f"{camera['rms_px']:.6f} px; {out['n_rejected']} of {out['n_corners']} corners left out"
        + (f", stills named: {', '.join(named)}" if named else "")
        + f"; projection uncertainty at infinity {inf['centre']:.3f} px at the centre, "
        f"{inf['worst_covered']:.3f} px worst where the stills were, {inf['worst_image']:.2f} px "
        "over the image"
    )
