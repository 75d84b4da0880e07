"""``cvsflow init`` on a camera-pose stream (a detector's output, as ETH ASL's hand-eye sets keep
one) and its marker body's pose stream: a session with ``camera_poses`` and ``pose_streams``.

Which file is which is read from the content, not the names: a camera's pose in the target's
frame has the target in front of the camera (the target's origin at positive depth in C) in
every row; the camera's marker body is, of the other pose streams beside it, the one whose
angular speed follows the camera's best (the cross-correlation's quality, the time offset's
coarse search of :func:`cvsflow.handeye.stream_offset`). Angular speed cannot tell a body's pose
from its inverse, nor two bodies on one rigid carrier, so streams that follow it about as well
(within :data:`TIE_QUALITY`) are told apart by the hand-eye fit itself
(:func:`cvsflow.handeye.estimate_streams`): the camera's body is the one a constant mounting
fits, with the smallest rotation residuals.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from cvsflow.cli.init_frames import STREAM_SUFFIXES
from cvsflow.exceptions import CvsflowError, InputError

log = logging.getLogger(__name__)

#: Share of rows with the target in front of the camera for a stream to be a camera-pose stream.
MIN_FRONT_SHARE = 0.99
#: Streams whose angular speed follows the camera's within this quality of the best one's are
#: told apart by the hand-eye fit's rotation residuals.
TIE_QUALITY = 0.1


def _streams(folder: Path) -> list:
    """(path, stream) of every file below ``folder`` that reads as a pose stream."""
    from cvsflow.io.mocap.formats import read_pose_stream

    out = []
    for p in sorted(p for p in folder.rglob("*") if p.suffix.lower() in STREAM_SUFFIXES and p.is_file()):
        try:
            out.append((p, read_pose_stream(p)))
        except CvsflowError as exc:
            log.debug("%s: not a pose stream (%s)", p, exc)
    return out


def front_share(stream) -> float:
    """Share of a pose stream's rows whose frame origin lies in front of the pose (positive z).

    Parameters
    ----------
    stream : DataFrame
        A pose stream table (``x_m .. qw``): ``T_A_X`` per row.

    Returns
    -------
    float
        The share of rows in which A's origin has positive z in X (1 for a camera's pose in the
        target's frame, the target being in view).
    """
    from cvsflow.io.mocap.streams import stream_T

    T = stream_T(stream)
    z = -np.einsum("nji,nj->ni", T[:, :3, :3], T[:, :3, 3])[:, 2]
    return float(np.mean(z > 0)) if len(z) else 0.0


def _best_body(camera, others, notes) -> Path | None:
    """The stream whose rotation follows the camera's best (coarse offset quality), noted; among
    those within :data:`TIE_QUALITY` of the best, the one the hand-eye fit leaves the smallest
    rotation residuals."""
    from cvsflow.handeye import stream_offset
    from cvsflow.io.mocap.streams import stream_T

    scored = []
    for p, s in others:
        try:
            off = stream_offset(camera["t_ns"].to_numpy(), stream_T(camera), s["t_ns"].to_numpy(),
                                stream_T(s))
        except CvsflowError as exc:
            log.debug("%s: no offset search (%s)", p, exc)
            continue
        quality = (off.get("coarse") or {}).get("quality")
        if off["dt_s"] is not None and quality is not None:
            scored.append((float(quality), p, off["dt_s"]))
    for quality, p, dt in sorted(scored, reverse=True):
        notes.append(f"pose stream {p}: its angular speed follows the camera's with quality {quality:.2f} "
                     f"at an offset of {1e3 * dt:+.1f} ms")  # fmt: skip
    if not scored:
        return None
    best = max(scored)
    tied = [p for q, p, _ in sorted(scored, reverse=True) if q >= best[0] - TIE_QUALITY]
    if len(tied) < 2:
        return best[1]
    streams = dict(others)
    residual = {p: _rotation_residual_rad(camera, streams[p]) for p in tied}
    fitted = {p: r for p, r in residual.items() if r is not None}
    if not fitted:
        return best[1]
    chosen = min(fitted, key=fitted.get)
    notes.append(f"{len(tied)} pose streams follow the camera's rotation about as well (within "
                 f"{TIE_QUALITY} of the best quality); the hand-eye fit with each leaves rotation "
                 "residuals of " + ", ".join(
                     f"{np.degrees(r):.2f} deg ({p.name})" if r is not None else f"no fit ({p.name})"
                     for p, r in residual.items()) + f": took {chosen.name}")  # fmt: skip
    return chosen


def _rotation_residual_rad(camera, body) -> float | None:
    """The robust scale of the rotation residuals (rad, mean over C's axes) of the hand-eye fit of
    a camera-pose stream to a body's stream; None where it cannot be fitted."""
    from cvsflow.handeye import estimate_streams
    from cvsflow.io.mocap.streams import stream_T

    try:
        fit = estimate_streams(camera["t_ns"].to_numpy(), stream_T(camera), body["t_ns"].to_numpy(),
                               stream_T(body))
    except CvsflowError as exc:
        log.debug("no hand-eye fit (%s)", exc)
        return None
    return float(np.mean([fit.sigma[f"rot_{a}"] for a in "xyz"]))


def build_camera_pose_config(path) -> tuple[dict, list[str]] | None:
    """A camera-pose session from a camera-pose CSV, or from a folder holding one; None if none.

    Parameters
    ----------
    path : str or Path
        A camera-pose stream (its folder is searched for the marker body's stream), or a folder:
        its first stream (by name) whose every row has the target in front of the camera
        (:data:`MIN_FRONT_SHARE`, :func:`front_share`) is the camera-pose stream.

    Returns
    -------
    (session, notes) or None
        ``camera_poses`` and ``pose_streams: {camera}`` (the body whose angular speed follows the
        camera's best; ``TODO`` when none does), and what was found, for the user to check; None
        for a folder without a camera-pose stream.

    Raises
    ------
    InputError
        A file given that does not read as a pose stream, or whose rows do not have the target
        in front of the camera.
    """
    from cvsflow.io.mocap.formats import read_pose_stream

    path = Path(path)
    notes: list[str] = []
    if path.is_file():
        try:
            camera = read_pose_stream(path)
        except CvsflowError as exc:
            raise InputError(f"{path}: not a camera-pose stream ({exc})") from exc
        share = front_share(camera)
        if share < MIN_FRONT_SHARE:
            raise InputError(f"{path}: the target is in front of the camera in {100 * share:.0f} % of its "
                             "rows (expected every row of a camera's pose in the target's frame, T_B_C); "
                             "is it a motion-capture body's stream?")  # fmt: skip
        cam_path, others = path, [s for s in _streams(path.parent) if s[0].resolve() != path.resolve()]
    else:
        streams = _streams(path)
        shares = [(front_share(s), p, s) for p, s in streams]
        cams = [(p, s) for share, p, s in shares if share >= MIN_FRONT_SHARE]
        if not cams:
            return None
        (cam_path, camera), others = cams[0], [(p, s) for p, s in streams if p != cams[0][0]]
        if len(cams) > 1:
            notes.append(f"{len(cams)} streams could be a camera's poses in the target frame "
                         f"({', '.join(str(p) for p, _ in cams)}); took the first: give the file to "
                         "choose (cvsflow init FILE)")  # fmt: skip
    t = camera["t_ns"].to_numpy(np.int64)
    notes.append(f"camera poses: {cam_path} ({camera.attrs.get('format')}, {len(t)} poses over "
                 f"{(t[-1] - t[0]) / 1e9:.1f} s; the target in front of the camera in every row)")
    body = _best_body(camera, others, notes)
    session = {"camera_poses": str(cam_path), "pose_streams": {"camera": str(body) if body else "TODO"}}
    if body is None:
        notes.append("no pose stream beside it follows the camera's rotation: set pose_streams.camera "
                     "(the camera's marker body in the mocap world)")  # fmt: skip
    notes.append("no board body: the target is taken as static in the mocap world (add "
                 "pose_streams.board if it moved); the sync stage estimates the time offset (set "
                 "dt_offset_s if it is known)")  # fmt: skip
    return session, notes
