"""Interchange files for a calibrated camera: OpenCV FileStorage, Kalibr camchain, ROS camera_info,
mrcal .cameramodel.

Each writer takes camera.yaml's content (``model``, ``K`` 3x3 in px, ``dist`` in OpenCV's order,
``width``, ``height`` in px, ``board`` with ``squares_x``, ``squares_y``, ``square_m``) and writes
one file atomically (through ``cvsflow.io.atomic_output``). Which format carries which lens model
(:data:`EXPORT_SUPPORT`):

==================  ======================  ==========================  ======================
format              opencv5 (k1 k2 p1 p2    opencv8 (+ k4 k5 k6,        fisheye4 (Kannala-
                    k3)                     rational)                   Brandt k1..k4)
==================  ======================  ==========================  ======================
OpenCV FileStorage  5 x 1                   8 x 1                       4 x 1, fisheye_model 1
ROS camera_info     ``plumb_bob``           ``rational_polynomial``     ``equidistant``
Kalibr camchain     ``radtan``, k3 dropped  refused: radtan has 4       ``equidistant``
                    (the shift it causes    terms; dropping k3..k6 is   (``pinhole-equi``)
                    computed and stated)    another lens
mrcal .cameramodel  ``LENSMODEL_OPENCV5``   ``LENSMODEL_OPENCV8``       refused: mrcal has no
                                                                        Kannala-Brandt model
==================  ======================  ==========================  ======================

ROS's and Kalibr's ``equidistant`` are ``cv2.fisheye``'s polynomial ``theta_d = theta (1 + k1
theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)`` with the same coefficients; mrcal's OPENCV5/8
intrinsics are ``fx fy cx cy`` and OpenCV's terms in OpenCV's order. A refused export raises an
:class:`~cvsflow.exceptions.InputError` that says why; :func:`write_all_formats` writes every
format the model allows and states the others.

Board convention: cvsflow's config counts *squares* (``squares_x``, ``squares_y``); OpenCV's
``findChessboardCorners`` and Kalibr's target files count *inner corners* (one fewer each way).
Every exported file says so in its header comment.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np
import yaml

from cvsflow.exceptions import InputError
from cvsflow.geometry import invert_T
from cvsflow.io.files import atomic_output

log = logging.getLogger(__name__)

#: Format name -> file name written beside camera.yaml.
FORMAT_FILES = {
    "opencv": "camera_opencv.yaml",
    "kalibr": "camchain.yaml",
    "ros": "camera_info.yaml",
    "mrcal": "camera.cameramodel",
}

#: Distortion terms of each lens model (cvsflow.calibration.lens).
N_DIST = {"opencv5": 5, "opencv8": 8, "fisheye4": 4}
#: (format, model) -> how the format carries the model: "exact", "drops k3", or why it cannot.
EXPORT_SUPPORT = {
    ("opencv", "opencv5"): "exact", ("opencv", "opencv8"): "exact",
    ("opencv", "fisheye4"): "exact",
    ("ros", "opencv5"): "exact", ("ros", "opencv8"): "exact", ("ros", "fisheye4"): "exact",
    ("kalibr", "opencv5"): "drops k3", ("kalibr", "fisheye4"): "exact",
    ("kalibr", "opencv8"): ("Kalibr's radtan model has 4 terms (k1 k2 p1 p2); dropping k3 and "
                            "the rational k4 k5 k6 would be another lens: use the OpenCV, ROS or "
                            "mrcal file, or calibrate with --model opencv5"),
    ("mrcal", "opencv5"): "exact", ("mrcal", "opencv8"): "exact",
    ("mrcal", "fisheye4"): ("mrcal has no Kannala-Brandt (equidistant) lens model: use the "
                            "OpenCV, ROS or Kalibr file"),
}
ROS_MODEL = {"opencv5": "plumb_bob", "opencv8": "rational_polynomial", "fisheye4": "equidistant"}
KALIBR_MODEL = {"opencv5": "radtan", "fisheye4": "equidistant"}
MRCAL_MODEL = {"opencv5": "LENSMODEL_OPENCV5", "opencv8": "LENSMODEL_OPENCV8"}

#: A k3 whose omission moves some pixel more than this (px) is warned about (Kalibr radtan).
K3_WARN_PX = 0.1


def _camera_arrays(camera: dict, source="camera.yaml") -> tuple[np.ndarray, np.ndarray, int, int]:
    """``K`` (3, 3) px, ``dist`` (the model's terms), width and height (px) of a camera.yaml
    mapping, checked against its ``model`` (``opencv5`` when absent)."""
    model = _model(camera, source)
    try:
        K = np.asarray(camera["K"], dtype=np.float64)
        dist = np.asarray(camera["dist"], dtype=np.float64).ravel()
        width, height = int(camera["width"]), int(camera["height"])
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{source}: expected keys K (3x3), dist, width, height ({exc})") from exc
    if K.shape != (3, 3) or dist.shape != (N_DIST[model],):
        raise InputError(
            f"{source}: K has shape {K.shape}, dist {dist.shape}; expected (3, 3) and "
            f"({N_DIST[model]},) for lens model {model}"
        )
    return K, dist, width, height


def _model(camera: dict, source="camera.yaml") -> str:
    """The camera's lens model, checked."""
    model = camera.get("model") or "opencv5"
    if model not in N_DIST:
        raise InputError(f"{source}: lens model {model!r}; expected one of {sorted(N_DIST)}")
    return model


def _check_support(camera: dict, fmt: str) -> str:
    """How ``fmt`` carries the camera's model, or an InputError saying why it cannot."""
    model = _model(camera)
    how = EXPORT_SUPPORT[(fmt, model)]
    if how not in ("exact", "drops k3"):
        raise InputError(f"a camera of lens model {model} cannot be written as {fmt}: {how}")
    return how


def _board_comment(camera: dict) -> str:
    board = camera.get("board") or {}
    if board.get("type") == "aprilgrid":
        size = (f"Kalibr AprilGrid of {board['tag_cols']}x{board['tag_rows']} tags (tagCols x tagRows), "
                f"tagSize {board['tag_size_m']} m, tagSpacing {board['tag_spacing']}")
    elif "squares_x" in board:
        sx, sy = int(board["squares_x"]), int(board["squares_y"])
        size = f"{sx}x{sy} squares = {sx - 1}x{sy - 1} inner corners, square {board['square_m']} m"
    else:
        size = "board size not recorded"
    return (
        "Board convention: cvsflow's config counts squares (squares_x, squares_y); OpenCV and "
        f"Kalibr count inner corners (one fewer each way). Calibration board: {size}."
    )


def k3_drop_shift_px(camera: dict, step_px: float = 8.0) -> float:
    """Largest pixel displacement caused by setting k3 = 0, over the whole image.

    Parameters
    ----------
    camera : dict
        camera.yaml content.
    step_px : float
        Spacing of the pixel grid tested (px); the image border is always included.

    Returns
    -------
    float
        max over the grid of ``|project(undistort(u; dist); dist with k3=0) - u|``, px.
    """
    K, dist, width, height = _camera_arrays(camera)
    us = np.unique(np.r_[np.arange(0.0, width, step_px), width - 1.0])
    vs = np.unique(np.r_[np.arange(0.0, height, step_px), height - 1.0])
    uu, vv = np.meshgrid(us, vs)
    px = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    norm = cv2.undistortPointsIter(
        px, K, dist, None, None, (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    ).reshape(-1, 2)
    pts = np.c_[norm, np.ones(len(norm))]
    dist0 = dist.copy()
    dist0[4] = 0.0
    reproj, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), K, dist0)
    return float(np.max(np.linalg.norm(reproj.reshape(-1, 2) - px.reshape(-1, 2), axis=1)))


def write_opencv_yaml(camera: dict, path) -> None:
    """OpenCV FileStorage YAML as OpenCV's calibration sample writes it.

    Keys ``image_width``, ``image_height`` (px), ``fisheye_model`` (1 for the fisheye model, as
    OpenCV's calibration sample writes it), ``camera_matrix`` (3x3 ``!!opencv-matrix``, px),
    ``distortion_coefficients`` (n x 1: k1 k2 p1 p2 k3 [k4 k5 k6], or the fisheye's k1..k4),
    ``avg_reprojection_error`` (px) when known.
    Written with ``cv2.FileStorage`` itself; read back with ``cv2.FileStorage(path, READ)``.

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``K`` (3x3, px), ``dist`` (k1 k2 p1 p2 k3), ``width``,
        ``height`` (px); ``rms_px`` and ``board`` used when present.
    path : str or Path
        Output file, written atomically.

    Returns
    -------
    None

    Raises
    ------
    InputError
        ``camera`` lacks K, dist, width or height, or they have the wrong shapes.
    """
    K, dist, width, height = _camera_arrays(camera)
    model = _model(camera)
    path = Path(path)
    with atomic_output(path, suffix=".yaml") as tmp:
        fs = cv2.FileStorage(str(tmp), cv2.FILE_STORAGE_WRITE)
        try:
            fs.writeComment(f"Written by cvsflow from camera.yaml, lens model {model}. "
                            + _board_comment(camera))
            fs.write("image_width", width)
            fs.write("image_height", height)
            fs.write("fisheye_model", int(model == "fisheye4"))
            fs.write("camera_matrix", K)
            fs.write("distortion_coefficients", dist.reshape(-1, 1))
            if camera.get("rms_px") is not None:
                fs.write("avg_reprojection_error", float(camera["rms_px"]))
        finally:
            fs.release()


def _dump_with_header(data: dict, header: str, path) -> None:
    text = "".join(f"# {line}\n" for line in header.splitlines())
    text += yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    with atomic_output(path) as tmp:
        Path(tmp).write_text(text)


def write_kalibr_camchain(camera: dict, path, topic: str = "/camera/image_raw") -> float:
    """Kalibr camchain YAML (one camera ``cam0``, ``pinhole`` + ``radtan`` or ``equidistant``).

    A fisheye4 camera is written exactly (``equidistant``); an opencv8 one is refused (an
    InputError saying why). Kalibr's radtan model has four coefficients (k1 k2 p1 p2): an
    opencv5 camera's k3 is dropped. The largest pixel
    shift that causes over the image is computed (``k3_drop_shift_px``), written in the file's
    comment, logged, and warned about when above ``K3_WARN_PX``.

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``K`` (3x3, px), ``dist`` (k1 k2 p1 p2 k3), ``width``,
        ``height`` (px); ``rms_px`` and ``board`` used when present.
    path : str or Path
        Output file.
    topic : str, default "/camera/image_raw"
        The ``rostopic`` Kalibr records for ``cam0``.

    Returns
    -------
    float
        That largest shift, px (0 for the fisheye).

    Raises
    ------
    InputError
        A malformed camera, or the 8-term rational model (radtan cannot carry it).
    """
    K, dist, width, height = _camera_arrays(camera)
    if _check_support(camera, "kalibr") == "exact":  # the fisheye: pinhole-equi, every term
        data = {"cam0": _kalibr_camera(K, dist, width, height, topic, "equidistant")}
        header = ("Kalibr camchain written by cvsflow from camera.yaml (pinhole-equi: the "
                  "fisheye4 model's k1..k4, exact).\n" + _board_comment(camera))
        _dump_with_header(data, header, path)
        return 0.0
    shift = k3_drop_shift_px(camera)
    note = (
        f"Kalibr radtan has no k3: k3 = {dist[4]:.6g} of camera.yaml was dropped; that moves "
        f"pixels by up to {shift:.3f} px over the {width}x{height} image."
    )
    if shift > K3_WARN_PX:
        log.warning(
            "%s: %s (over %.1f px: use the OpenCV or ROS file where k3 matters)", path, note, K3_WARN_PX
        )
    else:
        log.info("%s: %s", path, note)
    data = {"cam0": _kalibr_camera(K, dist, width, height, topic)}
    header = "Kalibr camchain written by cvsflow from camera.yaml.\n" + note + "\n" + _board_comment(camera)
    _dump_with_header(data, header, path)
    return shift


def _kalibr_camera(K, dist, width, height, topic, distortion_model="radtan") -> dict:
    """One camera of a Kalibr camchain (the first four distortion terms)."""
    return {
        "camera_model": "pinhole",
        "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
        "distortion_model": distortion_model,
        "distortion_coeffs": [float(v) for v in dist[:4]],
        "resolution": [width, height],
        "rostopic": topic,
    }


def write_kalibr_rig_camchain(cameras: list[dict], T_Ci_C0: list, path, topics=None) -> list[float]:
    """Kalibr camchain YAML of a rig: ``cam0`` .. ``camN`` with ``T_cn_cnm1`` from each to the next.

    Parameters
    ----------
    cameras : list of dict
        Each camera's ``camera.yaml`` mapping (``K``, ``dist``, ``width``, ``height``, px).
    T_Ci_C0 : list of array_like, shape (4, 4)
        Each camera's pose from camera 0 (``cvsflow.rig.extrinsics.stereo_extrinsics``; identity or
        omitted for camera 0 itself), metres: a point in C0 maps to Ci.
    path : str or Path
        Output file.
    topics : list of str, optional
        Each camera's ``rostopic``; default ``/cam<i>/image_raw``.

    Returns
    -------
    list of float
        Per camera, the largest pixel shift that dropping k3 causes (Kalibr radtan has no k3).

    Raises
    ------
    InputError
        A camera mapping without K, dist, width or height; a transform that is not 4x4 rigid.

    Notes
    -----
    Kalibr's ``T_cn_cnm1`` takes points from camera n-1 to camera n:
    ``T_Cn_C0 @ inv(T_Cn-1_C0)``.
    """
    if len(T_Ci_C0) == len(cameras) - 1:
        T_Ci_C0 = [np.eye(4)] + list(T_Ci_C0)
    if len(T_Ci_C0) != len(cameras) or len(cameras) < 2:
        raise InputError(f"{path}: a rig needs two or more cameras and one transform per camera; "
                         f"got {len(cameras)} cameras and {len(T_Ci_C0)} transforms")
    data, shifts = {}, []
    for i, camera in enumerate(cameras):
        K, dist, width, height = _camera_arrays(camera, source=f"camera {i}")
        if _model(camera) != "opencv5":
            raise InputError(f"{path}: camera {i} has lens model {_model(camera)}; the rig's "
                             "Kalibr camchain carries opencv5 cameras (radtan)")
        T = np.asarray(T_Ci_C0[i], float)
        if T.shape != (4, 4) or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6):
            raise InputError(f"{path}: T_Ci_C0 of camera {i} is not a 4x4 rigid transform")
        block = _kalibr_camera(K, dist, width, height,
                               topics[i] if topics else f"/cam{i}/image_raw")
        if i > 0:
            block["T_cn_cnm1"] = (T @ invert_T(np.asarray(T_Ci_C0[i - 1], float))).tolist()
        data[f"cam{i}"] = block
        shifts.append(k3_drop_shift_px(camera))
    header = ("Kalibr camchain of a camera rig written by cvsflow\n"
              "(cvsflow.rig.extrinsics.stereo_extrinsics).\n"
              "T_cn_cnm1 takes points from camera n-1 to camera n, metres.\n"
              + "k3 dropped (Kalibr radtan); largest pixel shift per camera: "
              + ", ".join(f"{v:.3f} px" for v in shifts) + "\n" + _board_comment(cameras[0]))
    _dump_with_header(data, header, path)
    return shifts


def write_ros_camera_info(camera: dict, path, camera_name: str = "camera") -> None:
    """ROS camera_info YAML as camera_calibration_parsers reads it.

    ``distortion_model`` ``plumb_bob`` (opencv5), ``rational_polynomial`` (opencv8) or
    ``equidistant`` (fisheye4), with the model's coefficients.

    ``projection_matrix`` is ``[K | 0]`` (monocular, unrectified); ``rectification_matrix`` identity.

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``K`` (3x3, px), ``dist`` (k1 k2 p1 p2 k3), ``width``,
        ``height`` (px); ``rms_px`` and ``board`` used when present.
    path : str or Path
        Output file.
    camera_name : str, default "camera"
        The ``camera_name`` field.

    Returns
    -------
    None
    """
    K, dist, width, height = _camera_arrays(camera)
    _check_support(camera, "ros")
    model = _model(camera)
    P = np.c_[K, np.zeros(3)]
    data = {
        "image_width": width,
        "image_height": height,
        "camera_name": str(camera_name),
        "camera_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in K.ravel()]},
        "distortion_model": ROS_MODEL[model],
        "distortion_coefficients": {"rows": 1, "cols": int(dist.size),
                                    "data": [float(v) for v in dist]},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [float(v) for v in np.eye(3).ravel()]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in P.ravel()]},
    }
    header = (f"ROS camera_info written by cvsflow from camera.yaml ({model}).\n"
              + _board_comment(camera))
    _dump_with_header(data, header, path)


def write_mrcal_cameramodel(camera: dict, path) -> None:
    """mrcal ``.cameramodel`` (its Python-literal text format): LENSMODEL_OPENCV5 or OPENCV8.

    The extrinsics are the identity (the camera is its own reference). No optimisation inputs
    are written, so mrcal cannot compute its own uncertainty from the file (cvsflow's is in
    camera.yaml: ``projection_uncertainty``).

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``model``, ``K`` (3x3, px), ``dist``, ``width``, ``height``.
    path : str or Path
        Output file.

    Returns
    -------
    None

    Raises
    ------
    InputError
        A malformed camera, or the fisheye model (mrcal has no Kannala-Brandt model).
    """
    K, dist, width, height = _camera_arrays(camera)
    _check_support(camera, "mrcal")
    intrinsics = [K[0, 0], K[1, 1], K[0, 2], K[1, 2], *dist.tolist()]
    text = ("# mrcal cameramodel written by cvsflow from camera.yaml\n"
            + "".join(f"# {line}\n" for line in _board_comment(camera).split(". "))
            + "{\n"
            f"    'lensmodel':  '{MRCAL_MODEL[_model(camera)]}',\n"
            "    # intrinsics are fx,fy,cx,cy,distortion0,distortion1,....\n"
            f"    'intrinsics': [ {', '.join(repr(float(x)) for x in intrinsics)} ],\n"
            "    # extrinsics are rt_fromref\n"
            "    'extrinsics': [ 0.0, 0.0, 0.0, 0.0, 0.0, 0.0 ],\n"
            f"    'imagersize': [ {width}, {height} ],\n"
            "}\n")
    with atomic_output(path) as tmp:
        Path(tmp).write_text(text)


WRITERS = {"opencv": write_opencv_yaml, "kalibr": write_kalibr_camchain,
           "ros": write_ros_camera_info, "mrcal": write_mrcal_cameramodel}


def write_camera_format(camera: dict, fmt: str, path) -> None:
    """Write ``camera`` in format ``fmt`` (``opencv``, ``kalibr``, ``ros`` or ``mrcal``) to ``path``.

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``K`` (3x3, px), ``dist`` (k1 k2 p1 p2 k3), ``width``,
        ``height`` (px); ``rms_px`` and ``board`` used when present.
    fmt : {"opencv", "kalibr", "ros", "mrcal"}
        Key of :data:`WRITERS`.
    path : str or Path
        Output file.

    Returns
    -------
    None

    Raises
    ------
    InputError
        An unknown ``fmt``, a malformed ``camera``, or a format that cannot carry its lens
        model (the message says why).
    """
    if fmt not in WRITERS:
        raise InputError(f"camera export format {fmt!r}: expected one of {sorted(WRITERS)}")
    WRITERS[fmt](camera, path)


def write_all_formats(camera: dict, folder) -> dict[str, Path | str]:
    """Write every interchange file the camera's lens model allows into ``folder``.

    Parameters
    ----------
    camera : dict
        A ``camera.yaml`` mapping: ``model`` (``opencv5`` when absent), ``K`` (3x3, px),
        ``dist``, ``width``, ``height`` (px); ``rms_px`` and ``board`` used when present.
    folder : str or Path
        Output folder (created when missing).

    Returns
    -------
    dict of str to Path or str
        Format name (``opencv``, ``kalibr``, ``ros``, ``mrcal``) -> the file written (names in
        ``FORMAT_FILES``), or the sentence saying why the format cannot carry the model.
    """
    folder = Path(folder)
    out = {}
    model = _model(camera)
    for fmt, name in FORMAT_FILES.items():
        how = EXPORT_SUPPORT[(fmt, model)]
        if how not in ("exact", "drops k3"):
            out[fmt] = (f"{name} not written: a camera of lens model {model} cannot be written as "
                        f"{fmt}: {how}")
            log.info("%s", out[fmt])
            continue
        write_camera_format(camera, fmt, folder / name)
        out[fmt] = folder / name
    return out
