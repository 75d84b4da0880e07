"""Known camera intrinsics from a file: ViSP's camera XML, cvsflow camera.yaml, OpenCV FileStorage.

ViSP's ``vpXmlParserCamera`` file holds one or more ``<camera>`` elements (``name``,
``image_width``, ``image_height``), each with one ``<model>`` per projection model:

- ``perspectiveProjWithoutDistortion``: ``px py u0 v0`` (px);
- ``perspectiveProjWithDistortion``: the same plus ``kud`` (undistorted to distorted) and
  ``kdu`` (distorted to undistorted).

ViSP projects with ``u = u0 + px x (1 + kud r^2)``, ``v = v0 + py y (1 + kud r^2)``,
``r^2 = x^2 + y^2`` (``vpMeterPixelConversion``), which is OpenCV's model with ``fx = px``,
``fy = py``, ``cx = u0``, ``cy = v0``, ``k1 = kud`` and every other term zero; ``kdu`` is the
inverse mapping's coefficient and is not needed to project. The Kannala-Brandt model is not
supported (it is not OpenCV's pinhole model).

Every reader returns the camera.yaml subset the pose and hand-eye code read: ``K`` (3x3 list,
px), ``dist`` ([k1, k2, p1, p2, k3]), ``width``, ``height`` (px), plus ``source`` (the file)
and, for ViSP, ``name`` and ``model``.
"""

from __future__ import annotations

import logging
import xml.parsers.expat
from pathlib import Path

import numpy as np

from cvsflow.exceptions import InputError

log = logging.getLogger(__name__)

MODEL_WITHOUT = "perspectiveProjWithoutDistortion"
MODEL_WITH = "perspectiveProjWithDistortion"
VISP_MODELS = (MODEL_WITHOUT, MODEL_WITH)


class _Node:
    """An XML element with its text and the line it starts on (for messages)."""

    def __init__(self, tag, line):
        self.tag, self.line, self.text, self.children = tag, line, "", []

    def find_all(self, tag):
        return [c for c in self.children if c.tag == tag]

    def find(self, tag):
        found = self.find_all(tag)
        return found[0] if found else None


def _parse_xml(path: Path) -> _Node:
    """The element tree of an XML file, each element carrying its line number."""
    parser = xml.parsers.expat.ParserCreate()
    root = _Node("#document", 0)
    stack = [root]

    def start(tag, _attrs):
        node = _Node(tag, parser.CurrentLineNumber)
        stack[-1].children.append(node)
        stack.append(node)

    def end(_tag):
        stack.pop()

    def chars(data):
        stack[-1].text += data

    parser.StartElementHandler, parser.EndElementHandler = start, end
    parser.CharacterDataHandler = chars
    try:
        parser.Parse(path.read_bytes(), True)
    except xml.parsers.expat.ExpatError as exc:
        raise InputError(f"{path}: not well-formed XML ({exc})") from exc
    return root


def _number(path, node, what, integer=False):
    """The number in element ``node`` (named ``what`` in messages)."""
    if node is None:
        raise InputError(f"{path}: {what} missing; expected <{what}> with a number")
    text = node.text.strip()
    try:
        value = float(text)
    except ValueError:
        raise InputError(
            f"{path}, line {node.line}, <{node.tag}>: {text!r} is not a number "
            f"(expected {'an integer' if integer else 'a number'})"
        ) from None
    if not np.isfinite(value) or (integer and value != int(value)):
        raise InputError(
            f"{path}, line {node.line}, <{node.tag}>: {text!r}; expected a finite "
            f"{'integer' if integer else 'number'}"
        )
    return int(value) if integer else value


def read_visp_camera(path, name=None, width=None, height=None, model="auto") -> dict:
    """Intrinsics of one camera in a ViSP camera XML file (``vpXmlParserCamera``).

    Parameters
    ----------
    path : str or Path
        The XML file.
    name : str, optional
        ``<name>`` of the camera to take; needed when the file holds cameras of several names.
    width, height : int, optional
        Image size (px) the camera must have been calibrated at, when several sizes are given.
    model : str
        ``perspectiveProjWithDistortion``, ``perspectiveProjWithoutDistortion``, or ``auto``
        (with distortion when present, else without).

    Returns
    -------
    dict
        ``K`` (3x3 list, px), ``dist`` ([kud, 0, 0, 0, 0]; zeros without distortion),
        ``width``, ``height`` (px), ``name``, ``model``, ``kdu`` (or None), ``source``.

    Raises
    ------
    InputError
        Missing or malformed file, no or several matching cameras, the model absent, or a
        value that is not a number (the message names the line).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found (expected a ViSP camera XML file)")
    if model not in ("auto", *VISP_MODELS):
        raise InputError(f"{path}: model {model!r}; expected auto or one of {list(VISP_MODELS)}")
    doc = _parse_xml(path)
    top = doc.children[0] if doc.children else None
    cams = top.find_all("camera") if top is not None else []
    if not cams:
        raise InputError(
            f"{path}: no <camera> element under the root; expected ViSP's vpXmlParserCamera "
            "layout <root><camera><name/><image_width/>...<model>...</model></camera></root>"
        )
    chosen = []
    for cam in cams:
        cam_name = (cam.find("name").text.strip() if cam.find("name") is not None else "")
        w = _number(path, cam.find("image_width"), "image_width", integer=True)
        h = _number(path, cam.find("image_height"), "image_height", integer=True)
        if name is not None and cam_name != name:
            continue
        if (width is not None and w != int(width)) or (height is not None and h != int(height)):
            continue
        chosen.append((cam, cam_name, w, h))
    found = [f"{n or '(unnamed)'} {w}x{h} (line {c.line})" for c, n, w, h in chosen]
    if not chosen:
        raise InputError(
            f"{path}: no camera matches name={name!r}, size={width}x{height}; the file has "
            f"{len(cams)} camera(s)"
        )
    if len(chosen) > 1:
        raise InputError(
            f"{path}: {len(chosen)} cameras match ({', '.join(found)}); give the name or image "
            "size to choose one"
        )
    cam, cam_name, w, h = chosen[0]
    models = {}
    for m in cam.find_all("model"):
        t = m.find("type")
        kind = t.text.strip() if t is not None else ""
        if kind not in VISP_MODELS:
            log.info("%s, line %d: model %r skipped (not a pinhole model)", path, m.line, kind)
            continue
        models[kind] = m
    want = model
    if model == "auto":
        want = MODEL_WITH if MODEL_WITH in models else MODEL_WITHOUT
    if want not in models:
        raise InputError(
            f"{path}, line {cam.line}: camera {cam_name!r} has no <model> of type {want}; it "
            f"has {sorted(models) or 'none of ' + str(list(VISP_MODELS))}"
        )
    m = models[want]
    px, py, u0, v0 = (_number(path, m.find(k), k) for k in ("px", "py", "u0", "v0"))
    if not (px > 0 and py > 0):
        raise InputError(f"{path}, line {m.line}: px={px}, py={py}; expected positive (px)")
    kud = _number(path, m.find("kud"), "kud") if want == MODEL_WITH else 0.0
    kdu = _number(path, m.find("kdu"), "kdu") if (want == MODEL_WITH and m.find("kdu") is not None) else None
    return {
        "K": [[px, 0.0, u0], [0.0, py, v0], [0.0, 0.0, 1.0]],
        "dist": [kud + 0.0, 0.0, 0.0, 0.0, 0.0],  # + 0.0 turns ViSP's "-0" into 0.0
        "width": w,
        "height": h,
        "name": cam_name,
        "model": want,
        "kdu": kdu,
        "source": str(path),
    }


#: cv::FileNode types (FileNode_INT .. FileNode_MAP), in words.
_NODE_KINDS = {0: "empty", 1: "an integer", 2: "a number", 3: "a string", 4: "a list (a YAML sequence)",
               5: "a mapping without rows, cols, dt and data"}


def _node_kind(node) -> str:
    return _NODE_KINDS.get(node.type() & 7, f"node type {node.type()}")


def _storage_matrix(fs, key, path, optional=False):
    """A FileStorage matrix node (``!!opencv-matrix``: rows, cols, dt, data), or InputError naming it."""
    import cv2

    node = fs.getNode(key)
    if node.empty():
        if optional:
            return None
        raise InputError(f"{path}: no {key} node; expected a 3x3 !!opencv-matrix (rows, cols, dt, data)")
    try:
        mat = node.mat() if node.isMap() else None
    except cv2.error:
        mat = None
    if mat is None:
        raise InputError(
            f"{path}: node {key} is {_node_kind(node)}; expected an !!opencv-matrix mapping "
            "(rows, cols, dt, data), as cv::FileStorage writes a cv::Mat"
        )
    return mat


def _storage_int(fs, key, path) -> int:
    """A positive integer node (image_width, image_height), or InputError naming it."""
    node = fs.getNode(key)
    value = node.real() if node.isInt() or node.isReal() else float("nan")
    if not (np.isfinite(value) and value > 0 and value == int(value)):
        what = "missing" if node.empty() else _node_kind(node)
        raise InputError(f"{path}: node {key} is {what}; expected the image size in px, a positive integer")
    return int(value)


def _read_opencv_storage(path: Path) -> dict:
    """camera_matrix / distortion_coefficients / image_width / image_height of a FileStorage."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise InputError(f"{path}: not readable as OpenCV FileStorage ({exc})") from exc
    try:
        if not fs.isOpened():
            raise InputError(f"{path}: not readable as OpenCV FileStorage")
        K = _storage_matrix(fs, "camera_matrix", path)
        dist = _storage_matrix(fs, "distortion_coefficients", path, optional=True)
        w, h = (_storage_int(fs, k, path) for k in ("image_width", "image_height"))
    finally:
        fs.release()
    if K is None or np.shape(K) != (3, 3):
        raise InputError(
            f"{path}: no 3x3 camera_matrix; expected a cvsflow camera.yaml (K, dist) or an "
            "OpenCV FileStorage file (camera_matrix, distortion_coefficients)"
        )
    d = np.zeros(5) if dist is None else np.asarray(dist, float).ravel()
    if d.size not in (4, 5, 8, 12, 14) or np.any(d[5:] != 0):
        raise InputError(
            f"{path}: distortion_coefficients has {d.size} values with rational or thin-prism "
            "terms; expected the 5-term model k1 k2 p1 p2 k3"
        )
    d = np.concatenate([d[:5], np.zeros(5 - min(d.size, 5))])
    return {"K": np.asarray(K, float).tolist(), "dist": d.tolist(), "width": w, "height": h,
            "source": str(path)}  # fmt: skip


def read_known_camera(path) -> dict:
    """Known intrinsics from ViSP XML (``.xml``), cvsflow camera.yaml or OpenCV FileStorage YAML.

    Parameters
    ----------
    path : str or Path
        The camera file. ``.xml``: ViSP XML, or OpenCV FileStorage XML when its first 400
        characters hold ``<opencv_storage>``; other suffixes: OpenCV YAML when it starts with
        ``%YAML``, else a cvsflow camera.yaml.

    Returns
    -------
    dict
        ``K`` (3x3 list, px), ``dist`` (5 values), ``width``, ``height`` (px), ``source``; a
        cvsflow camera.yaml keeps all its keys (``std`` among them).

    Raises
    ------
    InputError
        A missing file, or one of none of these kinds (the message says what was expected).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: camera file not found (ViSP XML, camera.yaml or OpenCV YAML)")
    if path.suffix.lower() == ".xml":
        head = path.read_text(errors="replace")[:400]
        if "<opencv_storage>" in head:
            return _read_opencv_storage(path)
        return read_visp_camera(path)
    if path.read_text(errors="replace").lstrip().startswith("%YAML"):
        return _read_opencv_storage(path)  # OpenCV's YAML 1.0 dialect, which PyYAML cannot read
    from cvsflow.io.camera_formats import _camera_arrays
    from cvsflow.io.files import read_yaml

    camera = read_yaml(path)
    K, dist, w, h = _camera_arrays(camera, source=str(path))
    return {**camera, "K": K.tolist(), "dist": dist.tolist(), "width": w, "height": h,
            "source": str(path)}  # fmt: skip
