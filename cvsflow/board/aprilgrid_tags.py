"""AprilTag detectors for Kalibr AprilGrids: raw tags in Kalibr's corner order, nothing checked.

Two backends, run as *passes* whose detections are merged (:func:`detect_tags`):

- :class:`AprilTagPass`: AprilRobotics' AprilTag 3 through ``pupil-apriltags``, its tag36h11
  family widened to the grid's 2-bit black border (the library's ctypes structs allow it; the
  original layout is checked before it is changed). It reads the small tags of a 640x480
  frame best (on the 30 real yac frames 956 of 1080 tags, against 548-770 for ArUco).
- :class:`ArucoPass`: OpenCV's ArUco detector (``DICT_APRILTAG_36h11``, ``markerBorderBits``
  from the grid). It still reads tags whose corner squares overlap them (ink spread), which
  AprilTag 3's segmentation merges into one blob.

``pupil-apriltags`` has wheels for Linux x86_64, macOS and Windows x86_64 but none for Linux
aarch64. Where it cannot be imported, :func:`default_passes` falls back to ArUco alone (612 of
the 1080 yac tags) with a warning logged once, and :func:`passes_name` says so in every
summary that records the detector.
"""

from __future__ import annotations

import atexit
import functools
import logging
from dataclasses import dataclass

import cv2
import numpy as np

from cvsflow.board.aprilgrid import FAMILY_DATA_BITS, AprilGrid

try:  # no wheel for Linux aarch64: the ArUco passes stand in (default_passes)
    import pupil_apriltags
except ImportError:  # pragma: no cover - depends on the platform
    pupil_apriltags = None

log = logging.getLogger(__name__)

#: ArUco returns a marker's corners clockwise from its top-left as cv2.aruco draws it; Kalibr
#: prints the tag turned 180 degrees, so ArUco corner a is Kalibr corner ARUCO_TO_KALIBR[a]
#: (on the yac frames ArUco's corner 0 lies at the tag's bottom-right in B).
ARUCO_TO_KALIBR = np.array([1, 0, 3, 2])


@dataclass(frozen=True)
class AprilTagPass:
    """One pass of AprilTag 3 (``pupil-apriltags``), its family widened to the grid's border.

    Attributes
    ----------
    upsample : int
        Detect on the image enlarged this many times (bicubic): the bits are sampled on the
        enlarged image, which reads more of the small tags (2-3 px a bit) of a 640x480 frame
        (yac: 956 tags with 2, 911 with 1, of 1080).
    quad_decimate : float
        AprilTag 3's ``quad_decimate`` (on the enlarged image).
    decode_sharpening : float
        AprilTag 3's ``decode_sharpening`` (set in the C struct: pupil-apriltags casts the
        argument to int, so 0.25 would become 0).
    open_px : int
        Grow the white by this many pixels of the enlarged image (a grey dilation) before
        detecting: it cuts a tag from corner squares that touch it, which AprilTag 3's
        segmentation otherwise joins to it.
    """

    upsample: int = 2
    quad_decimate: float = 2.0
    decode_sharpening: float = 0.25
    open_px: int = 0


@dataclass(frozen=True)
class ArucoPass:
    """One pass of OpenCV's ArUco detector (``DICT_APRILTAG_36h11``, the grid's border bits).

    Attributes
    ----------
    upsample : int
        Detect on the image enlarged this many times (bicubic).
    corner_refinement : int
        ``cv2.aruco.CORNER_REFINE_*``; none by default: the corners are refined on the tag's
        X junction afterwards, which ArUco's own refinements do not reach (its contour corners
        bend round the corner squares, 1.3-1.6 px off).
    pixels_per_cell : int
        ``perspectiveRemovePixelPerCell`` (OpenCV's 4 reads fewer Kalibr tags than 8).
    """

    upsample: int = 1
    corner_refinement: int = cv2.aruco.CORNER_REFINE_NONE
    pixels_per_cell: int = 8


#: The passes of :func:`detect_aprilgrid` with pupil-apriltags: AprilTag 3 reads the small tags
#: whose corner squares stop short of them; on a white-dilated copy also those whose corner
#: squares touch them; ArUco reads the tags whose corner squares overlap them. Together 1013 of
#: the 1080 yac tags (24-36 a frame; Kalibr's own detector 990).
APRILTAG_PASSES = (AprilTagPass(), AprilTagPass(open_px=1), ArucoPass())
#: The fallback without pupil-apriltags (612 of the 1080 yac tags).
ARUCO_PASSES = (ArucoPass(),)


def apriltag_available() -> bool:
    """True when ``pupil-apriltags`` could be imported (AprilTag 3 passes can run).

    Returns
    -------
    bool
    """
    return pupil_apriltags is not None


@functools.cache
def _warn_fallback() -> None:
    log.warning("AprilGrid: pupil-apriltags is not installed (no wheel for this platform); "
                "detecting tags with OpenCV's ArUco alone, which finds fewer small tags "
                "(612 against 1013 of the 1080 tags of the yac test frames)")


def default_passes() -> tuple:
    """The detector passes :func:`detect_aprilgrid` runs when none are given.

    Returns
    -------
    passes : tuple of AprilTagPass or ArucoPass
        ``APRILTAG_PASSES``, or ``ARUCO_PASSES`` (a warning logged once) where
        ``pupil-apriltags`` cannot be imported.
    """
    if apriltag_available():
        return APRILTAG_PASSES
    _warn_fallback()
    return ARUCO_PASSES


def passes_name(passes) -> str:
    """A short name of the detector passes, for the summaries that record how corners were found.

    Parameters
    ----------
    passes : tuple of AprilTagPass or ArucoPass

    Returns
    -------
    name : str
        E.g. ``"apriltag3 x2 + aruco"`` (the default) or ``"aruco"`` (the fallback), with
        the library versions: ``"apriltag3 x2 + aruco (pupil-apriltags 1.0.4.post11, opencv
        4.14.0)"``.
    """
    kinds = ["apriltag3" if isinstance(p, AprilTagPass) else "aruco" for p in passes]
    parts = [k if kinds.count(k) == 1 else f"{k} x{kinds.count(k)}" for k in dict.fromkeys(kinds)]
    versions = []
    if "apriltag3" in kinds and pupil_apriltags is not None:
        versions.append(f"pupil-apriltags {_pupil_version()}")
    versions.append(f"opencv {cv2.__version__}")
    return " + ".join(parts) + f" ({', '.join(versions)})"


def _pupil_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("pupil-apriltags")
    except PackageNotFoundError:  # pragma: no cover - imported but not installed as a package
        return "unknown"


# AprilTag 3 detectors made in this process, closed at exit (see _close_apriltag_detector).
_APRILTAG_DETECTORS: list = []


def _close_apriltag_detector(detector) -> None:
    """Free a pupil-apriltags detector in the safe order.

    pupil-apriltags' ``Detector.__del__`` frees the tag families before the detector, whose
    destructor then reads them (a use-after-free, seen as a segfault at exit in one run of
    six). Destroying the detector first and clearing its pointer makes ``__del__`` a no-op.
    """
    ptr, detector.tag_detector_ptr = detector.tag_detector_ptr, None
    if ptr is None:
        return
    libc = detector.libc
    libc.apriltag_detector_destroy.restype = None
    libc.apriltag_detector_destroy(ptr)
    libc.tag36h11_destroy.restype = None
    for family in detector.tag_families.values():
        libc.tag36h11_destroy(family)
    detector.tag_families = {}


@atexit.register
def _close_apriltag_detectors() -> None:
    while _APRILTAG_DETECTORS:
        _close_apriltag_detector(_APRILTAG_DETECTORS.pop())
    _apriltag_detector.cache_clear()


@functools.lru_cache(maxsize=8)
def _apriltag_detector(border_bits: int, quad_decimate: float, decode_sharpening: float):
    """An AprilTag 3 detector of tag36h11 with a ``border_bits`` black border (one per process)."""
    if pupil_apriltags is None:
        raise ImportError(
            "an AprilTagPass needs pupil-apriltags (pip install pupil-apriltags; it has no Linux "
            "aarch64 wheel), or give passes=(ArucoPass(),)"
        )
    detector = pupil_apriltags.Detector(families="tag36h11", nthreads=1, quad_decimate=quad_decimate,
                                        quad_sigma=0.0, refine_edges=1, decode_sharpening=0.0)
    detector.tag_detector_ptr.contents.decode_sharpening = float(decode_sharpening)
    family = detector.tag_families["tag36h11"].contents
    # AprilTag 3 describes a family's layout in its C struct: the bits' positions (bit_x,
    # bit_y) in a square of width_at_border cells whose outer ring is the black border. The
    # classic families have a 1-bit border (width 8 for 36h11); a Kalibr tag has 2 bits, so
    # the square is 10 cells and every bit moves in by one. The quick-decode table is built
    # from the codes only and stays valid.
    data_bits = FAMILY_DATA_BITS["tag36h11"]
    layout = (family.width_at_border, family.total_width, family.nbits, bool(family.reversed_border))
    if layout != (data_bits + 2, data_bits + 4, data_bits**2, False):
        _close_apriltag_detector(detector)
        raise RuntimeError(
            f"pupil-apriltags {_pupil_version()}: unexpected tag36h11 layout (width_at_border, "
            f"total_width, nbits, reversed_border) = {layout}; expected (8, 10, 36, False), so "
            "its border cannot be widened to the AprilGrid's (pin pupil-apriltags as pyproject.toml does)"
        )
    shift = border_bits - 1
    family.width_at_border = data_bits + 2 * border_bits
    family.total_width = data_bits + 2 * border_bits + 2
    for i in range(family.nbits):
        family.bit_x[i] += shift
        family.bit_y[i] += shift
    _APRILTAG_DETECTORS.append(detector)
    return detector


@functools.lru_cache(maxsize=8)
def _aruco_detector(border_bits: int, corner_refinement: int, pixels_per_cell: int):
    params = cv2.aruco.DetectorParameters()
    params.markerBorderBits = border_bits
    params.cornerRefinementMethod = corner_refinement
    params.perspectiveRemovePixelPerCell = pixels_per_cell
    dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    return cv2.aruco.ArucoDetector(dictionary, params)


def _enlarged(gray: np.ndarray, factor: int) -> np.ndarray:
    if factor == 1:
        return gray
    return cv2.resize(gray, None, fx=factor, fy=factor, interpolation=cv2.INTER_CUBIC)


def _cv_px(uv_px: np.ndarray, factor: int, centre: float) -> np.ndarray:
    """Pixels of an image enlarged ``factor`` times, whose pixel centres are at ``centre``
    (0 for OpenCV, 0.5 for AprilTag 3), as OpenCV pixels of the original image."""
    return (uv_px + 0.5 - centre) / factor - 0.5


def _apriltag_tags(gray, grid: AprilGrid, options: AprilTagPass):
    detector = _apriltag_detector(grid.border_bits, float(options.quad_decimate),
                                  float(options.decode_sharpening))
    image = _enlarged(gray, options.upsample)
    if options.open_px:
        image = cv2.dilate(image, np.ones((2 * options.open_px + 1,) * 2, np.uint8))
    found = detector.detect(np.ascontiguousarray(image))
    ids = np.array([d.tag_id for d in found], dtype=np.int64)
    # AprilTag 3 returns the corners bottom-left first, counter-clockwise in the tag's own
    # frame: Kalibr's order already. Its pixel centres are at +0.5 (a 0.50 px bias in u and v
    # on renders otherwise).
    corners = np.array([d.corners for d in found], dtype=np.float64).reshape(-1, 4, 2)
    return ids, _cv_px(corners, options.upsample, centre=0.5)


def _aruco_tags(gray, grid: AprilGrid, options: ArucoPass):
    detector = _aruco_detector(grid.border_bits, int(options.corner_refinement),
                               int(options.pixels_per_cell))
    found, aruco_ids, _ = detector.detectMarkers(_enlarged(gray, options.upsample))
    if aruco_ids is None:
        return np.zeros(0, np.int64), np.zeros((0, 4, 2))
    corners = np.array(found, dtype=np.float64).reshape(-1, 4, 2)
    corners[:, ARUCO_TO_KALIBR] = corners.copy()
    return aruco_ids.ravel().astype(np.int64), _cv_px(corners, options.upsample, centre=0.0)


def _new_detections(ids, corners, new_ids, new_corners):
    """The detections of (new_ids, new_corners) not already in (ids, corners): same id,
    centres within a quarter of the tag's side."""
    if not len(ids):
        return new_ids, new_corners
    keep = np.ones(len(new_ids), dtype=bool)
    centres = corners.mean(axis=1)
    for i, (t, q) in enumerate(zip(new_ids, new_corners, strict=True)):
        same = np.flatnonzero(ids == t)
        if len(same):
            side = np.linalg.norm(q[1] - q[0])
            keep[i] = np.min(np.linalg.norm(centres[same] - q.mean(axis=0), axis=1)) >= 0.25 * side
    return new_ids[keep], new_corners[keep]


def detect_tags(gray: np.ndarray, grid: AprilGrid, passes: tuple | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Raw tag detections in Kalibr's corner order, before any check or refinement.

    Parameters
    ----------
    gray : ndarray, shape (H, W), uint8
    grid : AprilGrid
        Only ``family`` and ``border_bits`` are used here.
    passes : tuple of AprilTagPass or ArucoPass, optional
        Detector runs, in order (default :func:`default_passes`); a later pass's detection of
        an id already found at the same place (centres within a quarter of a side) is dropped,
        one elsewhere is kept for :func:`cvsflow.board.aprilgrid_detect.consistent_tags` to
        judge.

    Returns
    -------
    tag_ids : ndarray, shape (T,), int64
        Decoded ids, any id of the family (not yet checked against the grid).
    corners_px : ndarray, shape (T, 4, 2), float64
        Each tag's corners k = 0..3 (bottom-left, bottom-right, top-right, top-left in B),
        distorted pixels, pixel centres at integers.

    Raises
    ------
    ImportError
        An AprilTagPass without pupil-apriltags.
    """
    if passes is None:
        passes = default_passes()
    if isinstance(passes, AprilTagPass | ArucoPass):
        passes = (passes,)
    if not passes:
        raise ValueError("passes: expected at least one AprilTagPass or ArucoPass")
    ids, corners = np.zeros(0, np.int64), np.zeros((0, 4, 2))
    for p in passes:
        if isinstance(p, AprilTagPass):
            t, c = _apriltag_tags(gray, grid, p)
        elif isinstance(p, ArucoPass):
            t, c = _aruco_tags(gray, grid, p)
        else:
            raise TypeError(f"pass {p!r}: expected an AprilTagPass or an ArucoPass")
        t, c = _new_detections(ids, corners, t, c)
        ids, corners = np.concatenate([ids, t]), np.concatenate([corners, c])
    return ids, corners
