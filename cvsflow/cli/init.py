"""``cvsflow init``: a session config written from a recording folder, for the user to check."""

from __future__ import annotations

import re
from pathlib import Path

from cvsflow.errors import CvsflowError, InputError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v")


MOCAP_SUFFIXES = (".csv", ".c3d", ".tsv")


#: Inner-corner sizes ``cvsflow init`` tries (OpenCV sample, common printed boards, the demo's).
COMMON_INNER = ((9, 6), (8, 6), (7, 5), (7, 6), (10, 7), (6, 4), (5, 4), (11, 8), (8, 5))


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
