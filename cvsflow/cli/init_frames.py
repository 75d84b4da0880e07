"""``cvsflow init`` on a recording of timestamped frames and pose streams (ASL/EuRoC, as Kalibr and
yac keep one): the session's ``frames``, ``pose_streams`` and, when both were stamped by one
clock, ``dt_offset_s: 0``.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from cvsflow.exceptions import CvsflowError

log = logging.getLogger(__name__)

#: Files a pose stream may be in (ASL/EuRoC CSV, TUM and ETH text).
STREAM_SUFFIXES = (".csv", ".txt", ".tum")

#: Fewest frames for which ``cvsflow init`` keeps the seed method: its five held-out folds need
#: ten whole-board frames each (evaluate/heldout_seed), and frames of a folder are few.
MIN_SEED_FRAMES = 100


def find_frames(folder: Path):
    """The timestamped frame folder of a recording, or None.

    The recording folder itself (an ASL camera folder, a dataset folder holding one ``cam*``
    folder, or images named by integer ns), else the first ASL camera folder below it (a folder
    with ``data.csv`` and ``data/``), by name.

    Parameters
    ----------
    folder : Path

    Returns
    -------
    (Path, DataFrame) or None
        The folder to name as ``frames`` and its :func:`cvsflow.io.frames.frame_list`.
    """
    from cvsflow.io.frames import frame_list

    cams = sorted(p for p in folder.rglob("*")
                  if p.is_dir() and (p / "data.csv").is_file() and (p / "data").is_dir())  # fmt: skip
    for candidate in (folder, *cams):
        try:
            return candidate, frame_list(candidate)
        except CvsflowError:
            continue
    return None


def _path_length_m(stream) -> float:
    xyz = stream[["x_m", "y_m", "z_m"]].to_numpy(float)
    return float(np.linalg.norm(np.diff(xyz, axis=0), axis=1).sum()) if len(xyz) > 1 else 0.0


def add_frame_session(session: dict, notes: list, folder: Path, frames_dir: Path, frames) -> None:
    """Set ``frames``, ``pose_streams`` and, for one clock, ``dt_offset_s`` of a session.

    Every file below ``folder`` that reads as a pose stream (:func:`read_pose_stream`, format
    detected) is a candidate: the one that travels farthest is the camera's body, the one that
    travels least the board's (a board is usually still), each named in the notes with its path
    length. When the frames' times lie inside the camera stream's span the two were stamped by
    one clock: ``dt_offset_s: 0`` (a note says so and how to have it estimated instead).

    Parameters
    ----------
    session : dict
        The session block being built; changed in place.
    notes : list of str
        What was found, for the user to check; appended to.
    folder : Path
        The recording folder.
    frames_dir : Path
        :func:`find_frames`' folder.
    frames : DataFrame
        Its frame list (``t_ns``).

    Returns
    -------
    None
        ``session`` and ``notes`` are changed in place.
    """
    from cvsflow.io.mocap.formats import read_pose_stream

    session["frames"] = str(frames_dir)
    t = frames["t_ns"].to_numpy(np.int64)
    notes.append(f"frames: {frames_dir} ({len(t)} frames, {(t[-1] - t[0]) / 1e9:.1f} s, "
                 f"{frames.attrs['layout']}; times exact, ns)")  # fmt: skip
    if len(t) < MIN_SEED_FRAMES:
        session["methods"] = ["se3"]
        notes.append(f"methods: [se3]: {len(t)} frames are too few for the seed method's held-out "
                     f"folds (at least 10 whole-board frames in each of 5)")  # fmt: skip
    own = {Path(frames.attrs["source"]).resolve()}
    streams = []
    for p in sorted(p for p in folder.rglob("*") if p.suffix.lower() in STREAM_SUFFIXES and p.is_file()):
        if p.resolve() in own:
            continue
        try:
            stream = read_pose_stream(p)
        except CvsflowError as exc:
            log.debug("%s: not a pose stream (%s)", p, exc)
            continue
        streams.append((_path_length_m(stream), p, stream))
    session["pose_streams"] = {"camera": "TODO", "board": "TODO"}
    if not streams:
        notes.append("no pose stream (ASL/EuRoC, TUM or ETH CSV) found: set pose_streams.camera and "
                     ".board")  # fmt: skip
        return
    streams.sort(key=lambda s: s[0])
    for length, p, stream in streams:
        notes.append(f"pose stream: {p} ({stream.attrs.get('format')}, {len(stream)} poses, travels "
                     f"{length:.2f} m)")  # fmt: skip
    camera = streams[-1]
    session["pose_streams"]["camera"] = str(camera[1])
    if len(streams) > 1:
        session["pose_streams"]["board"] = str(streams[0][1])
        notes.append(f"pose_streams: the camera's body is the one that travels farthest "
                     f"({camera[1].relative_to(folder)}), the board's the one that travels least "
                     f"({streams[0][1].relative_to(folder)}); check")  # fmt: skip
    else:
        notes.append("one pose stream only: set pose_streams.board (the board's body)")
    t_c = camera[2]["t_ns"].to_numpy(np.int64)
    inside = float(np.mean((t >= t_c[0]) & (t <= t_c[-1])))
    if inside >= 0.5:
        session["dt_offset_s"] = 0.0
        notes.append(f"dt_offset_s: 0: {100 * inside:.0f} % of the frame times lie inside the camera "
                     "stream's span (one clock); delete it to have the sync stage estimate the "
                     "offset, which needs the camera to move at the frames")  # fmt: skip
    else:
        notes.append(f"the frames ({t[0]}..{t[-1]} ns) and the camera stream ({t_c[0]}..{t_c[-1]} ns) "
                     "hardly overlap: two clocks; the sync stage estimates the offset (set "
                     "dt_offset_s if it is known)")  # fmt: skip
