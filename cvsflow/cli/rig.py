"""``cvsflow calibrate-rig``: calibrate two or more fixed cameras and their relative poses."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cvsflow.cli.args import board_from_args
from cvsflow.exceptions import InputError


def cmd_calibrate_rig(args) -> int:
    """``cvsflow calibrate-rig``: each camera from its stills, then the rig from the shared ones.

    Stills taken at the same instant by several cameras must carry the same file name in each
    camera's folder (``shared_003.png`` in ``cam0/`` and ``cam1/``); a camera's other stills
    serve its own intrinsics. Writes ``cam<i>/`` (camera.yaml, calib_corners.parquet and the
    OpenCV, Kalibr and ROS files, as ``cvsflow calibrate``), ``rig.yaml`` (each camera's
    ``T_Ci_C0`` with standard errors, baseline, views shared) and ``camchain.yaml`` (Kalibr,
    all cameras, ``T_cn_cnm1``) into ``args.out``.

    Parameters
    ----------
    args : argparse.Namespace
        ``dirs`` (one stills folder per camera, camera 0 first), ``inner`` ((nx, ny) inner
        corners) with ``square_m`` (m), or ``target`` (a Kalibr target file: an AprilGrid's
        views count with the corners they show), ``out`` (folder), ``force`` (replace files of
        the same names there), ``subpix_window_px``, ``min_images``, ``min_shared_views``.

    Returns
    -------
    int
        Exit code, 0 (errors are raised as :class:`CvsflowError` and reported by ``main``).

    Raises
    ------
    InputError
        Fewer than two folders, a folder without images, a missing ``--square-m``, an
        unreadable target file, a file this command writes already in ``out`` without
        ``--force`` (checked before anything is computed).
    ConfigError
        A target file of an unsupported type or with a missing or invalid key.
    CalibrationError
        A camera that cannot be calibrated, or too few shared views (named).
    """
    import cv2

    from cvsflow.io.camera_formats import FORMAT_FILES, write_all_formats, write_kalibr_rig_camchain
    from cvsflow.io.files import refuse_overwrite, write_parquet, write_yaml
    from cvsflow.io.media import list_stills, read_gray
    from cvsflow.rig import calibrate_rig

    if len(args.dirs) < 2:
        raise InputError("calibrate-rig: give one stills folder per camera, two or more")
    board = board_from_args(args)
    out = Path(args.out)
    per_camera = ("camera.yaml", "calib_corners.parquet", *FORMAT_FILES.values())
    refuse_overwrite([out / "rig.yaml", out / "camchain.yaml"]
                     + [out / f"cam{i}" / n for i in range(len(args.dirs)) for n in per_camera],
                     args.force, "cvsflow calibrate-rig")
    cv2.setNumThreads(1)
    stills = []
    for d in args.dirs:
        paths = list_stills(d)
        if not paths:
            raise InputError(f"{d}: no images (png, jpg, ...) in the stills folder")
        stills.append([(p.name, read_gray(p)) for p in paths])
    cameras, rig, corners = calibrate_rig(
        stills, board, min_shared_views=args.min_shared_views,
        subpix_window_px=args.subpix_window_px, min_images=args.min_images)
    for i, (camera, table) in enumerate(zip(cameras, corners, strict=True)):
        write_yaml(camera, out / f"cam{i}" / "camera.yaml")
        write_parquet(table, out / f"cam{i}" / "calib_corners.parquet")
        write_all_formats(camera, out / f"cam{i}")
    rig_doc = {
        "cameras": [{"camera": 0, "folder": str(args.dirs[0]), "T_Ci_C0": np.eye(4).tolist()}]
        + [{"folder": str(args.dirs[c["camera"]])} | {k: v for k, v in c.items() if k != "start_T_Ci_C0"}
           for c in rig["cameras"]],
        "rms_px": rig["rms_px"],
        "sigma_px": rig["sigma_px"],
        "n_views": rig["n_views"],
        "views": rig["views"],
        "board": board,
    }
    write_yaml(rig_doc, out / "rig.yaml")
    write_kalibr_rig_camchain(cameras, [np.eye(4)] + [np.array(c["T_Ci_C0"]) for c in rig["cameras"]],
                              out / "camchain.yaml")
    for i, camera in enumerate(cameras):
        K = np.asarray(camera["K"])
        print(f"camera {i}: {camera['n_used']} stills, fx {K[0, 0]:.3f} fy {K[1, 1]:.3f} px, "
              f"RMS {camera['rms_px']:.4f} px")
    for c in rig["cameras"]:
        s = c["std"]
        print(f"camera {c['camera']} from camera 0: baseline {c['baseline_m']:.4f} +- "
              f"{1e3 * c['baseline_std_m']:.2f} mm over {c['n_shared_views']} shared views; t "
              + " ".join(f"{v:.4f}" for v in c["t_m"]) + " m +- "
              + " ".join(f"{1e3 * s[k]:.2f}" for k in ("tx", "ty", "tz")) + " mm")
    print(f"wrote {out / 'rig.yaml'}, {out / 'camchain.yaml'} and cam0..cam{len(cameras) - 1}/")
    return 0
