"""Which stages each configured session can run, or why it cannot run what it asks for.

A session names its inputs (``calib_dir``, ``video``, ``vicon``, or a ``synth`` block that
renders all three). Every input it names must be used: a video is turned into poses, which need
the camera's intrinsics, from the session's own stills or, with ``camera: <other session>``,
from another session's calibration. A session that names something it cannot use stops the
run before any job starts, with a message that says what to add.
"""

from __future__ import annotations

import logging

from cvsflow.charuco import charuco_board
from cvsflow.errors import ConfigError

logger = logging.getLogger(__name__)

#: Stages a session can run, in DAG order.
STAGES = ("calibrate", "poses", "vicon", "pairs")


def camera_session(name: str, sessions: dict) -> str | None:
    """The session whose ``camera.yaml`` gives ``name`` its intrinsics.

    Parameters
    ----------
    name : str
        Session key in ``config["sessions"]``.
    sessions : dict
        ``config["sessions"]``, validated against the schema.

    Returns
    -------
    str or None
        ``name`` itself when it has stills (``calib_dir`` or ``synth``), the session named by
        its ``camera`` key, or None when it has no camera.

    Raises
    ------
    ConfigError
        ``camera`` names an unknown session, itself, or a session without stills, or the
        session has both stills and ``camera``.
    """
    s = sessions[name]
    own = "calib_dir" in s or "synth" in s
    if "camera" not in s:
        return name if own else None
    other = s["camera"]
    where = f"config: sessions.{name}.camera"
    if own:
        raise ConfigError(
            f"{where}: the session has its own stills (calib_dir or synth) and also names "
            f"camera: {other}; expected one of the two"
        )
    if other not in sessions:
        raise ConfigError(
            f"{where}: names session {other!r}, which is not in sessions "
            f"(expected one of {sorted(sessions)})"
        )
    if other == name or not ("calib_dir" in sessions[other] or "synth" in sessions[other]):
        raise ConfigError(
            f"{where}: session {other!r} has no stills of its own (expected a session with "
            f"calib_dir or synth, whose results/{other}/camera.yaml is reused)"
        )
    return other


def session_stages(name: str, sessions: dict) -> tuple[str, ...]:
    """The stages session ``name`` runs; every input it names is used by one of them.

    Parameters
    ----------
    name : str
        Session key in ``config["sessions"]``.
    sessions : dict
        ``config["sessions"]``, validated against the schema.

    Returns
    -------
    tuple of str
        A subset of `STAGES`, in DAG order: ``calibrate`` (own stills), ``poses`` (video and a
        camera), ``vicon`` (Vicon export and markers), ``pairs`` (all of them: sync, pairs,
        optimisers, held-out evaluation).

    Raises
    ------
    ConfigError
        The session names a video without a camera, a Vicon export without markers, or
        nothing to process; a ChArUco board without a usable marker_m or dictionary.
    """
    s = sessions[name]
    where = f"config: sessions.{name}"
    if isinstance(s.get("board"), dict) and s["board"].get("type") == "charuco":
        try:
            charuco_board(s["board"])
        except ConfigError as exc:
            raise ConfigError(f"{where}.{exc}") from exc
    synth = "synth" in s
    cam = camera_session(name, sessions)
    has_video = synth or "video" in s
    has_vicon = synth or "vicon" in s
    stages = []
    if cam == name:
        stages.append("calibrate")
    if has_video:
        if cam is None:
            raise ConfigError(
                f"{where}: names a video ({s['video']}) but no calib_dir: its poses need the "
                f"camera's intrinsics. Expected calib_dir (a folder of ~15 stills of the board) "
                f"or camera: <session> to reuse the calibration of another session with the "
                f"same camera and settings"
            )
        stages.append("poses")
    if has_vicon:
        if "markers" not in s:
            raise ConfigError(
                f"{where}: names a Vicon export but no markers: expected markers.camera.names "
                f"and markers.board.names (the marker names of each rigid body in the export)"
            )
        stages.append("vicon")
    if "poses" in stages and "vicon" in stages:
        stages.append("pairs")
    if not stages:
        raise ConfigError(
            f"{where}: nothing to process; expected calib_dir, video (with calib_dir or "
            f"camera), vicon (with markers) or a synth block"
        )
    logger.debug("session %s: stages %s", name, ", ".join(stages))
    return tuple(stages)


def check_sessions(sessions: dict) -> dict[str, tuple[str, ...]]:
    """`session_stages` of every session; the first inconsistent one raises ConfigError.

    Parameters
    ----------
    sessions : dict
        ``config["sessions"]``, validated against the schema: session name to its block.

    Returns
    -------
    dict of str to tuple of str
        Session name to its stages (:func:`session_stages`), in the order of ``sessions``.

    Raises
    ------
    ConfigError
        The first session (in order) whose inputs are inconsistent.
    """
    return {name: session_stages(name, sessions) for name in sessions}
