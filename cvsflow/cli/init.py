"""``cvsflow init``: a session config written from a recording folder, for the user to check.

One camera (stills, a video, a motion-capture export anywhere in the folder) gives a plain
session; two or more camera folders (each with its stills and its video) give a rig session
(a ``cameras:`` list, :func:`cvsflow.workflow.sessions.expand_rig_sessions`).
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

from cvsflow.cli.init_bag import build_bag_config, is_bag
from cvsflow.cli.init_frames import add_frame_session, find_frames
from cvsflow.cli.init_streams import build_camera_pose_config
from cvsflow.exceptions import CvsflowError, InputError

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")
# bare H.264 / HEVC streams (Raspberry Pi cameras): no frame times until remuxed
RAW_STREAM_SUFFIXES = (".h264", ".264", ".h265", ".265", ".hevc")


MOCAP_SUFFIXES = (".csv", ".c3d", ".tsv")
#: Files a Kalibr target description may be in.
TARGET_SUFFIXES = (".yaml", ".yml")


#: Inner-corner sizes ``cvsflow init`` tries (OpenCV sample, common printed boards, the demo's).
COMMON_INNER = ((9, 6), (8, 6), (7, 5), (7, 6), (10, 7), (6, 4), (5, 4), (11, 8), (8, 5))

#: Name of a folder of shared views (stills every camera of a rig took at one instant), in a
#: camera folder (``rec/<camera>/shared/``) or at the top (``rec/shared/<camera>/``).
SHARED = "shared"

#: Fewest file names a camera's shared stills must have in common with camera 0's
#: (``stereo_extrinsics``' default ``min_shared_views``).
MIN_SHARED_VIEWS = 3


def _n_images(d: Path) -> int:
    from cvsflow.io.media import IMAGE_SUFFIXES

    return sum(1 for p in d.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES)


def _find_stills(folder: Path, exclude=()):
    best = None
    for d in sorted([folder, *[p for p in folder.rglob("*") if p.is_dir()]]):
        if any(d == e or e in d.parents for e in exclude):
            continue
        n = _n_images(d)
        if n >= 3 and (best is None or n > best[1]):
            best = (d, n)
    return best


def _try_inner_sizes(still: Path, first=()):
    import cv2

    from cvsflow.io.media import read_gray

    gray = read_gray(still)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
    # A size not on the still costs about 0.4 s (640x480): the sizes found already go first.
    for nx, ny in [*first, *(s for s in COMMON_INNER if s not in first)]:
        found, _ = cv2.findChessboardCorners(gray, (nx, ny), flags=flags)
        if found:
            return nx, ny
    return None


def _inner_sizes_found(stills_dir: Path, first=None) -> tuple[list, int]:
    """Inner-corner sizes found on the first stills of a folder, and how many were tried.

    With ``first`` (a list, extended in place), the sizes found on earlier stills are tried
    first on the next ones; without it every still tries `COMMON_INNER` in its order.
    """
    from cvsflow.io.media import list_stills

    # The first stills may not show the whole board: try a few before giving up.
    tried = list_stills(stills_dir)[:5]
    found = []
    for still in tried:
        try:
            size = _try_inner_sizes(still, () if first is None else tuple(first))
        except InputError as exc:  # an empty or cut still: left out, as the calibration does
            log.warning("%s; left out", exc)
            continue
        if size is not None:
            found.append(size)
            if first is not None and size not in first:
                first.append(size)
    return found, len(tried)


def _videos(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.suffix.lower() in VIDEO_SUFFIXES)


def _add_mocap(session: dict, notes: list, candidates) -> tuple[list[str], list[str]]:
    """Set ``mocap.file`` (and ``mocap.format``) from the first readable export; its marker and body names."""
    from cvsflow.io.mocap.formats import read_mocap
    from cvsflow.io.mocap.markers import marker_names

    names: list[str] = []
    system_bodies: list[str] = []
    session["mocap"] = {"file": "TODO"}
    for p in candidates:
        try:
            export = read_mocap(p)
        except CvsflowError as exc:
            notes.append(f"{p}: not a motion-capture export ({exc})")
            continue
        names = marker_names(export.markers)
        if export.bodies is not None and len(export.bodies):
            system_bodies = list(dict.fromkeys(export.bodies["body"]))
        session["mocap"] = {"file": str(p), "format": export.format}
        solved = f", bodies solved by the system: {', '.join(system_bodies)}" if system_bodies else ""
        notes.append(f"motion capture: {p} ({export.format}), markers {', '.join(names) or 'none'}{solved}")
        break
    if session["mocap"]["file"] == "TODO":
        notes.append("no Nexus CSV, C3D, Motive CSV or QTM TSV export found: set mocap.file")
    return names, system_bodies


def _find_target(folder: Path, notes: list):
    """The first Kalibr target file in the folder (sorted paths), or None; noted either way.

    A YAML file counts when :func:`cvsflow.io.targets.read_target_board` reads a board from it
    (Kalibr's target keys, yac's ``calib_target`` block, hand_eye_calibration's keys); one that
    names a ``target_type`` cvsflow cannot use is noted with the reason.
    """
    from cvsflow.io.files import read_yaml
    from cvsflow.io.targets import read_target_board

    for p in sorted(q for q in folder.rglob("*") if q.suffix.lower() in TARGET_SUFFIXES and q.is_file()):
        try:
            board = read_target_board(p)
        except CvsflowError as exc:
            try:
                data = read_yaml(p)
            except CvsflowError:
                continue
            block = data.get("calib_target")
            if "target_type" in data or (isinstance(block, dict) and "target_type" in block):
                notes.append(f"{p}: a target file cvsflow cannot use ({exc})")
            continue
        notes.append(f"board: Kalibr target file {p} ({_describe(board)}); set as target, "
                     "no chessboard searched on the stills")
        return p
    return None


def _describe(board: dict) -> str:
    if board.get("type") == "aprilgrid":
        return (f"AprilGrid of {board['tag_cols']}x{board['tag_rows']} tags, {board['tag_size_m']} m, "
                f"spacing {board['tag_spacing']}")
    return f"checkerboard of {board['squares_x']}x{board['squares_y']} squares, {board['square_m']} m"


def _add_board(session: dict, notes: list, inner, stills_dir=None) -> None:
    # findChessboardCorners also finds a ChArUco board's grid; its markers say which it is
    if stills_dir is not None and _add_charuco(session, notes, stills_dir, inner):
        return
    if inner is None:
        session["board"] = {"squares_x": "TODO", "squares_y": "TODO", "square_m": "TODO"}
        notes.append(f"no chessboard of the sizes {COMMON_INNER} (inner corners) found: set board")
    else:
        session["board"] = {"squares_x": inner[0] + 1, "squares_y": inner[1] + 1, "square_m": "TODO"}
        notes.append(
            f"board: {inner[0]}x{inner[1]} inner corners found = {inner[0] + 1}x{inner[1] + 1} squares "
            "(cvsflow counts squares); measure square_m in metres"
        )


def _add_charuco(session: dict, notes: list, stills_dir, inner=None) -> bool:
    """A ``type: charuco`` board from what the first stills show (False: no ChArUco markers,
    or a row length other than the chessboard ``inner`` found)."""
    from cvsflow.board import guess_charuco_board
    from cvsflow.io.media import list_stills, read_stills

    images, _ = read_stills(list_stills(stills_dir)[:5])  # an empty or cut still: left out
    guess = guess_charuco_board(gray for _, gray in images)
    if guess is None or (inner is not None and guess["squares_x"] not in (None, inner[0] + 1)):
        return False
    sx, sy = guess["squares_x"], guess["squares_y_min"]
    session["board"] = {"type": "charuco", "squares_x": sx or "TODO", "squares_y": "TODO",
                        "square_m": "TODO", "marker_m": "TODO", "dictionary": guess["dictionary"]}
    notes.append(f"board: ChArUco markers of {guess['dictionary']} (or a larger dictionary of its "
                 f"family), ids up to {guess['max_id']} seen")
    if sx is None:
        notes.append("the markers fit no ChArUco layout of 3 to 24 squares a row (OpenCV >= 4.6 "
                     "pattern, square (0, 0) black): set squares_x and squares_y")
        return True
    if guess["max_id"] + 1 == (sx * sy) // 2:
        session["board"]["squares_y"] = sy
        notes.append(f"board: {sx}x{sy} squares (the highest marker id seen, {guess['max_id']}, "
                     f"is the last of a {sx}x{sy} board; check); measure square_m in metres")
    else:
        notes.append(f"board: {sx} squares a row, at least {sy} rows (from the highest marker id "
                     "seen): set squares_y")
    notes.append(f"marker_m is about {guess['marker_share']:.2f} x square_m (from the stills): "
                 "measure it")
    return True


def _add_markers(session: dict, notes: list, names, system_bodies, camera_keys=("cam",)) -> None:
    """``markers`` (and ``mocap.bodies_from``) guessed from subject names containing ``camera_keys``."""
    subjects: dict[str, list[str]] = {}
    for n in names:
        subjects.setdefault(n.split(":")[0] if ":" in n else "(no subject)", []).append(n)
    if subjects:
        notes.append("subjects in the export: " + "; ".join(
            f"{k} ({len(v)} markers)" for k, v in subjects.items()))
    cam = next((v for key in camera_keys for k, v in subjects.items() if key in k.lower()), ["TODO"])
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

        # The camera's keys in order of preference (a rig's "rig" before a camera's "cam").
        camera_body = next((b for k in camera_keys for b in system_bodies if k in b.lower()), "TODO")
        session["markers"] = {"camera": {"system_body": camera_body},
                              "board": {"system_body": guess(("board", "chess"))}}
        notes[-1] = ("the export has no markers: mocap.bodies_from is system; check "
                     "markers.*.system_body against the bodies listed above")
    elif system_bodies:
        notes.append("the export also has the system's own bodies: set mocap.bodies_from: system "
                     "and markers.<body>.system_body to use them instead of fitting the markers")


def camera_folders(folder) -> list[Path]:
    """The camera folders of a rig recording, or [] for a one-camera recording.

    A rig is two or more direct subfolders (other than a top-level ``shared``) that each hold a
    stills folder (3 or more images, a ``shared`` folder not counted), at least one of which also
    holds a video; a subfolder with a video or a ``shared`` folder is then a camera folder too.
    One camera's stills in several subfolders with the video elsewhere
    (``rec/calib_a``, ``rec/calib_b``, ``rec/take.mp4``) stays a one-camera recording, as before.

    Parameters
    ----------
    folder : str or Path
        The recording folder.

    Returns
    -------
    list of Path
        The camera folders, sorted by name (camera 0 first), or [] when the folder is not a rig.
    """
    folder = Path(folder)
    subs = sorted(p for p in folder.iterdir() if p.is_dir() and p.name.lower() != SHARED)
    with_stills = [p for p in subs if _find_stills(p, exclude=_own_shared(p)) is not None]
    if len(with_stills) >= 2 and any(_videos(p) for p in with_stills):
        # A rig: a subfolder with a video or shared views but no stills of its own is a camera
        # too (its calib_dir a TODO), not left out.
        return [p for p in subs if p in with_stills or _videos(p) or _own_shared(p)]
    return []


def _own_shared(camera_dir: Path) -> list[Path]:
    return [p for p in camera_dir.iterdir() if p.is_dir() and p.name.lower() == SHARED]


def _shared_dirs(folder: Path, cams: list[Path], notes: list) -> dict:
    """Camera folder name to its folder of shared views (``<camera>/shared`` or ``shared/<camera>``)."""
    top = [p for p in folder.iterdir() if p.is_dir() and p.name.lower() == SHARED]
    top_subs = {p.name: p for t in top for p in t.iterdir() if p.is_dir()}
    found = {}
    for c in cams:
        own, other = _own_shared(c), top_subs.pop(c.name, None)
        if own and other is not None:
            raise InputError(f"{own[0]} and {other}: two folders of shared views for camera folder "
                             f"{c}; keep one (rec/<camera>/{SHARED}/ or rec/{SHARED}/<camera>/)")
        if own or other is not None:
            found[c.name] = own[0] if own else other
    for name, p in sorted(top_subs.items()):
        notes.append(f"{p}: no camera folder named {name}; these shared views are not used")
    return found


def _check_shared(shared: dict, cams: list[Path], notes: list) -> dict:
    """The shared dirs when every camera's stills pair by file name with camera 0's, else {}.

    ``stereo_extrinsics`` pairs views by file name: a view only some cameras have is not used
    (noted), and a camera with fewer than MIN_SHARED_VIEWS names in common with camera 0 would
    stop rig_extrinsics, so then no camera gets a shared_dir (noted, naming the folders).
    """
    from cvsflow.io.media import list_stills

    if not shared:
        notes.append(f"no folders of shared views ({SHARED}/ in each camera folder or "
                     f"{SHARED}/<camera>/ at the top): rig_extrinsics will not run; add shared_dir "
                     "to every camera to run it")
        return {}
    missing = [c for c in cams if c.name not in shared]
    if missing:
        notes.append(f"{', '.join(str(c) for c in missing)}: no folder of shared views while "
                     f"{', '.join(str(shared[k]) for k in sorted(shared))} has one; shared_dir left "
                     "out of every camera (rig_extrinsics needs one per camera)")
        return {}
    names = {c.name: {p.name for p in list_stills(shared[c.name])} for c in cams}
    ref = cams[0].name
    ok = True
    for c in cams[1:]:
        common = names[c.name] & names[ref]
        if names[c.name] != names[ref]:
            unpaired = {k: sorted(names[k] - common) for k in (ref, c.name)}
            notes.append(
                f"{shared[c.name]} ({len(names[c.name])} stills) and {shared[ref]} "
                f"({len(names[ref])}): {len(common)} file names in common; unpaired, not used: "
                + "; ".join(f"{k} {', '.join(v[:5])}{' ...' if len(v) > 5 else ''}"
                            for k, v in unpaired.items() if v))
        if len(common) < MIN_SHARED_VIEWS:
            ok = False
            notes.append(
                f"{shared[c.name]}: only {len(common)} shared stills with the same file name as in "
                f"{shared[ref]} (rig_extrinsics needs {MIN_SHARED_VIEWS}; a view taken at one "
                "instant must have the same file name in every camera's folder): shared_dir left "
                "out of every camera; rename them and add it")
    return shared if ok else {}


def build_rig_config(folder, cams: list[Path]) -> tuple[dict, list[str]]:
    """Rig session config guessed from a recording folder with camera folders, and notes.

    Parameters
    ----------
    folder : str or Path
        The recording folder.
    cams : list of Path
        Its camera folders (:func:`camera_folders`), camera 0 (the rig's reference, C0) first.

    Returns
    -------
    session : dict
        ``cameras`` (per camera ``name``, ``calib_dir``, ``video`` and, when every camera has
        shared views that pair by file name, ``shared_dir``), ``vicon``, ``board`` (or
        ``target``, a Kalibr target file found in the folder), ``markers`` (TODO where nothing
        or more than one candidate was found).
    notes : list of str
        What was found and what the user must check; a problem names its folder.

    Raises
    ------
    InputError
        Two camera folders whose names give the same camera name, or a camera with shared
        views both in its folder and in the top-level ``shared`` folder.
    """
    folder = Path(folder)
    notes = [f"rig: {len(cams)} camera folders ({', '.join(c.name for c in cams)}); camera 0 "
             f"(the reference, C0) is {cams[0].name}, the first by name: reorder cameras to change it"]
    names = [re.sub(r"[^A-Za-z0-9_-]", "_", c.name) for c in cams]
    if len(set(names)) != len(names):
        raise InputError(f"{folder}: camera folders {[c.name for c in cams]} give camera names "
                         f"{names}, not distinct: rename the folders")
    shared = _check_shared(_shared_dirs(folder, cams, notes), cams, notes)
    target = _find_target(folder, notes)
    cameras, found, seen_sizes = [], [], []
    for c, name in zip(cams, names, strict=True):
        cam = {"name": name}
        if name != c.name:
            notes.append(f"{c}: camera name {name} (letters, digits, _ and - only)")
        stills = _find_stills(c, exclude=_own_shared(c))
        if stills is None:
            cam["calib_dir"] = "TODO"
            notes.append(f"{c}: no folder with 3 or more stills in this camera folder ({SHARED}/ not "
                         f"counted): set cameras[{name}].calib_dir")
        else:
            cam["calib_dir"] = str(stills[0])
            if target is None:
                sizes, tried = _inner_sizes_found(stills[0], first=seen_sizes)
                found += sizes
                notes.append(f"{name}: stills {stills[0]} ({stills[1]} images), board found on "
                             f"{len(sizes)} of the first {tried}")
            else:
                notes.append(f"{name}: stills {stills[0]} ({stills[1]} images)")
        others = [d for d in sorted(c.rglob("*")) if d.is_dir() and stills and d != stills[0]
                  and not any(s == d or s in d.parents for s in _own_shared(c)) and _n_images(d) >= 3]
        if others:
            notes.append(f"{c}: also stills in {', '.join(str(d) for d in others)}; took "
                         f"{stills[0]} (the most images), check calib_dir")
        videos = _videos(c)
        if len(videos) == 1:
            cam["video"] = str(videos[0])
            notes.append(f"{name}: video {videos[0]}")
        elif not videos:
            cam["video"] = "TODO"
            notes.append(f"{c}: no video in this camera folder: set cameras[{name}].video")
        else:
            cam["video"] = "TODO"
            notes.append(f"{c}: {len(videos)} videos in this camera folder "
                         f"({', '.join(p.name for p in videos)}): set cameras[{name}].video to "
                         "this camera's take")
        if c.name in shared:
            cam["shared_dir"] = str(shared[c.name])
        cameras.append(cam)
    if shared:
        notes.append("shared views: " + ", ".join(f"{k} {v}" for k, v in shared.items()))
    inside = set(cams)
    stray = [v for v in _videos(folder) if not inside & set(v.parents)]
    if stray:
        notes.append(f"videos outside the camera folders, not used: {', '.join(map(str, stray))}")
    session: dict = {"cameras": cameras}
    # The rig's one export is at the top; one inside a camera folder is only a fall-back.
    mocap = sorted(p for p in folder.rglob("*") if p.suffix.lower() in MOCAP_SUFFIXES)
    mocap = [p for p in mocap if not inside & set(p.parents)] + [p for p in mocap if inside & set(p.parents)]
    marker_list, system_bodies = _add_mocap(session, notes, mocap)
    inner = max(set(found), key=found.count) if found else None
    if len(set(found)) > 1:
        notes.append(f"the cameras' stills show different boards {sorted(set(found))} (inner "
                     f"corners): took {inner}, the most common; a rig watches one board, check")
    first_stills = next((Path(c["calib_dir"]) for c in cameras if c.get("calib_dir") != "TODO"), None)
    if target is not None:
        session["target"] = str(target)
    else:
        _add_board(session, notes, inner, first_stills)
    # The rig body is the bar the cameras sit on: named like a rig, bar or camera.
    _add_markers(session, notes, marker_list, system_bodies, camera_keys=("rig", "bar", "cam"))
    notes.append("markers.camera is the rig body: the markers on what every camera is fixed to")
    return session, notes


def build_session_config(folder, layout="auto") -> tuple[dict, list[str]]:
    """Session config guessed from a recording folder, and notes for the user to check.

    Parameters
    ----------
    folder : str or Path
        The recording folder, searched recursively for a stills folder (3 or more images),
        a video (``VIDEO_SUFFIXES``) and a motion-capture export (``MOCAP_SUFFIXES``), or a
        timestamped frame folder and pose streams (:mod:`cvsflow.cli.init_frames`). When it
        holds two or more camera folders (:func:`camera_folders`), a rig session is built
        instead (:func:`build_rig_config`).
    layout : {"auto", "rig", "mono"}
        ``"auto"``: a rig when :func:`camera_folders` finds one; ``"rig"``: a rig or an error
        saying what a rig folder needs; ``"mono"``: one camera whatever the subfolders hold
        (the first stills folder and video found).

    Returns
    -------
    session : dict
        ``calib_dir``, ``video``, ``mocap``, ``board``, ``markers`` (entries marked TODO where
        nothing was found), or for a frame folder ``frames``, ``pose_streams`` and, for one
        clock, ``dt_offset_s`` instead of ``video``, ``mocap`` and ``markers``; for a rig
        ``cameras`` instead of ``calib_dir`` and ``video``; a Kalibr target file in the folder
        (:func:`cvsflow.io.targets.read_target_board`) gives ``target`` (its path) instead of
        ``board``.
    notes : list of str
        What was found and what the user must check.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: recording folder not found")
    if layout not in ("auto", "rig", "mono"):
        raise InputError(f"init: layout must be auto, rig or mono, not {layout!r}")
    cams = camera_folders(folder) if layout != "mono" else []
    if cams:
        return build_rig_config(folder, cams)
    if layout == "rig":
        raise InputError(
            f"{folder}: not a rig recording: expected two or more camera folders "
            f"({folder}/<camera>/), each with a folder of 3 or more stills and one with a video; "
            "shared views in <camera>/shared/ or shared/<camera>/")
    if not _videos(folder) and find_frames(folder) is None and _find_stills(folder) is None:
        found = build_camera_pose_config(folder)  # a detector's camera-pose stream: no images
        if found is not None:
            return found
    notes = []
    session: dict = {}
    stills = _find_stills(folder)
    target = _find_target(folder, notes)
    inner = None
    if stills is None:
        session["calib_dir"] = "TODO"
        notes.append("no folder with 3 or more stills found: set calib_dir")
    else:
        session["calib_dir"] = str(stills[0])
        notes.append(f"stills: {stills[0]} ({stills[1]} images)")
        found, tried = _inner_sizes_found(stills[0]) if target is None else ([], 0)
        if found:
            inner = max(set(found), key=found.count)
            notes.append(f"board found on {found.count(inner)} of the first {tried} stills")
    frames = find_frames(folder)
    if frames is not None:  # timestamped frames and pose streams (ASL/EuRoC): no video, no export
        add_frame_session(session, notes, folder, *frames)
    else:
        names, system_bodies = _add_video_and_mocap(session, notes, folder)
    if target is not None:
        session["target"] = str(target)
    else:
        _add_board(session, notes, inner, None if stills is None else stills[0])
    if frames is None:
        _add_markers(session, notes, names, system_bodies)
    return session, notes


def _add_video_and_mocap(session: dict, notes: list, folder: Path) -> tuple[list[str], list[str]]:
    """Set ``video`` and ``mocap`` of a session from a recording folder; the export's marker and body
    names."""
    videos = _videos(folder)
    session["video"] = str(videos[0]) if videos else "TODO"
    notes.append(f"video: {videos[0]}" if videos else "no video found: set video")
    raw = sorted(p for p in folder.rglob("*") if p.suffix.lower() in RAW_STREAM_SUFFIXES)
    if raw and not videos:
        notes.append(f"{raw[0]}: a raw stream without frame times: `cvsflow remux {raw[0]} "
                     "--timestamps <its --save-pts file> --out video.mp4` (or --fps), then set "
                     "video to that MP4")
    if len(videos) > 1:
        notes.append(f"{len(videos)} videos found; took the first, check")
    mocap = sorted(p for p in folder.rglob("*") if p.suffix.lower() in MOCAP_SUFFIXES)
    return _add_mocap(session, notes, mocap)


def cmd_init(args) -> int:
    """``cvsflow init``: write a session config guessed from a recording folder.

    The YAML (``sessions: {name: ...}``) is preceded by comment lines with the notes of
    :func:`build_session_config`; the notes are printed too.

    Parameters
    ----------
    args : argparse.Namespace
        ``dir`` (recording folder, or a ROS bag: :func:`cvsflow.cli.init_bag.build_bag_config`,
        whose topic listing is printed and written as comments), ``out`` (file to write, default
        ``DIR/cvsflow_session.yaml``; for a bag ``<bag>_session.yaml`` beside it), ``name``
        (session name, default the folder's or the bag's name;
        characters other than letters, digits, _ and - become _), ``layout`` (auto, rig or
        mono: :func:`build_session_config`). A folder of two or more camera folders gives a
        rig session (:func:`build_rig_config`) unless ``layout`` is mono.

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

    from cvsflow.io.files import atomic_output

    folder = Path(args.dir)
    bag = is_bag(folder)
    single = folder.is_file() and not bag  # a camera-pose CSV
    beside = bag or single
    default_out = folder.parent / f"{folder.stem}_session.yaml" if beside else folder / "cvsflow_session.yaml"
    out = Path(args.out) if args.out else default_out
    if out.exists():
        raise InputError(f"{out}: exists; cvsflow init never overwrites a file (give --out)")
    listing = ""
    if bag:
        session, notes, listing = build_bag_config(folder)
        print(listing)
    elif single:
        session, notes = build_camera_pose_config(folder)
    else:
        session, notes = build_session_config(folder, getattr(args, "layout", "auto"))
    # A session name is a wildcard value: letters, digits, _ and - only (cvsflow/workflow/rules/common.smk).
    name = re.sub(r"[^A-Za-z0-9_-]", "_", args.name or (folder.stem if beside else folder.resolve().name))
    text = "# Session config written by `cvsflow init`: check every line, fill every TODO.\n"
    text += "".join(f"# {line}\n" for line in listing.splitlines())
    # cvsflow run CONFIG runs that file's sessions alone; its paths are as init wrote them.
    text += f"# Use: cvsflow run {out} (from the folder cvsflow init ran in: paths are relative to it)\n"
    text += "".join(f"# {n}\n" for n in notes)
    text += yaml.safe_dump({"sessions": {name: session}}, sort_keys=False, default_flow_style=None)
    with atomic_output(out) as tmp:
        Path(tmp).write_text(text)
    for n in notes:
        print(n)
    print(f"wrote {out}")
    return 0
