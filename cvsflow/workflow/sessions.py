"""Which stages each configured session can run, or why it cannot run what it asks for.

A session names its inputs (``calib_dir``, ``video`` or a timestamped ``frames`` folder,
``mocap.file`` or two ``pose_streams``, a ROS bag's image and pose topics in a ``bag`` block, or a
``synth`` block that renders all three). Instead of images a session may name a detector's
``camera_poses`` stream (the camera's pose in the target frame per timestamp): it then needs no
board, stills or intrinsics, only the motion capture of the camera's marker body (the board's
may be left out: the target is then static in the mocap world). Every input
it names must be used: a video is turned into poses, which need the camera's intrinsics, from the
session's own stills or, with ``camera: <other session>``, from another session's calibration.
A session that names something it cannot use stops the run before any job starts, with a message
that says what to add.
"""

from __future__ import annotations

import logging

from cvsflow.board import aprilgrid_from_board, board_type, charuco_board
from cvsflow.exceptions import ConfigError, CvsflowError

logger = logging.getLogger(__name__)

#: Stages a session can run, in DAG order (``camera_poses`` and ``pose_fit``: a session whose
#: camera input is a camera-pose stream, instead of ``poses`` and ``pairs``).
STAGES = ("calibrate", "poses", "camera_poses", "mocap", "pairs", "pose_fit")

#: What a camera-pose session must not name, and why.
_NOT_WITH_CAMERA_POSES = {
    "video": "expected one camera input: the camera-pose stream or the video",
    "frames": "expected one camera input: the camera-pose stream or the frame folder",
    "synth": "a synth block renders a video; expected one camera input",
    "calib_dir": "a camera-pose stream needs no intrinsics (there are no images); leave out calib_dir",
    "camera": "a camera-pose stream needs no intrinsics (there are no images); leave out camera",
    "target": "the stream's poses are already in the target's frame (no board is detected); leave out "
              "target",
    "board": "the stream's poses are already in the target's frame (no board is detected); leave out "
             "board",
    "methods": "the session is fitted by the pose-level fit (results/<session>/pose_fit/), not by seed or "
               "se3; leave out methods",
    "cameras": "a rig takes videos; expected one camera-pose stream per session",
}

def mocap_file(session: dict) -> str | None:
    """The motion-capture export a session names.

    Parameters
    ----------
    session : dict
        One entry of ``config["sessions"]`` (after `upgrade_config`).

    Returns
    -------
    str or None
        ``mocap.file``, or None when the session names no export.
    """
    return (session.get("mocap") or {}).get("file")


def _move(parent: dict, old: str, new_parent: dict, new: str, old_name: str, new_name: str) -> str:
    if new in new_parent:
        raise ConfigError(f"config: both {old_name} (deprecated) and {new_name} are given; keep {new_name}")
    new_parent[new] = parent.pop(old)
    return f"config: {old_name} is deprecated, use {new_name} (read as {new_name} this time)"


def upgrade_config(config: dict) -> list[str]:
    """Rename the deprecated keys of a config in place, before validation.

    A config that uses an old name still runs, with a warning naming the new one: ``vicon``
    (the top-level block) is ``mocap``; ``sessions.<s>.vicon`` (the export's path) is
    ``sessions.<s>.mocap.file``; ``sessions.<s>.synth.vicon_lead_s`` is ``mocap_lead_s``.

    Parameters
    ----------
    config : dict
        The config as loaded (Snakemake's ``config``); changed in place.

    Returns
    -------
    list of str
        One deprecation warning per key renamed, naming the old and the new key.

    Raises
    ------
    ConfigError
        A deprecated key and its new name are both given.
    """
    notes = []
    old, new = "sessions.{}.vicon", "sessions.{}.mocap.file"
    old_lead, new_lead = "sessions.{}.synth.vicon_lead_s", "sessions.{}.synth.mocap_lead_s"
    if "vicon" in config:
        notes.append(_move(config, "vicon", config, "mocap", "vicon", "mocap"))
    for name, s in (config.get("sessions") or {}).items():
        if not isinstance(s, dict):
            continue
        if "vicon" in s:
            mocap = s.setdefault("mocap", {})
            if not isinstance(mocap, dict):
                continue
            notes.append(_move(s, "vicon", mocap, "file", old.format(name), new.format(name)))
        synth = s.get("synth")
        if isinstance(synth, dict) and "vicon_lead_s" in synth:
            notes.append(_move(synth, "vicon_lead_s", synth, "mocap_lead_s", old_lead.format(name),
                               new_lead.format(name)))
    return notes


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


#: The two marker bodies a bag block may give the poses of.
BAG_BODIES = ("camera", "board")


def bag_settings(session: str, cfg: dict) -> dict | None:
    """A session's ``bag`` block with its defaults, checked; None when it has none.

    Parameters
    ----------
    session : str
        Session key, for messages.
    cfg : dict
        ``config["sessions"][session]`` (validated against the schema).

    Returns
    -------
    dict or None
        ``path`` (str, or a list of str for a split ROS 1 recording), ``time``, ``image``
        (``{"topic", "time"}`` or None), ``camera_body`` and ``board_body`` (``{"topic",
        "parent", "child", "time"}`` or None).

    Raises
    ------
    ConfigError
        ``image_topic`` beside a ``video`` or ``frames``; a body topic beside ``mocap.file`` or
        ``pose_streams``; one body's topic
        without the other's; a block that names no topic.
    """
    block = cfg.get("bag")
    if block is None:
        return None
    where = f"config: sessions.{session}.bag"
    time = block.get("time", "header")
    out = {"path": block["path"], "time": time, "image": None, "camera_body": None, "board_body": None}
    if "image_topic" in block:
        for key in ("video", "frames"):
            if key in cfg:
                raise ConfigError(f"{where}.image_topic: the session also names {key} ({cfg[key]}); expected "
                                  f"one camera input: the bag's image topic or the {key}")  # fmt: skip
        out["image"] = {"topic": block["image_topic"], "time": time}
    named = [b for b in BAG_BODIES if f"{b}_body" in block]
    if named:
        if len(named) == 1:
            missing = next(b for b in BAG_BODIES if b not in named)
            raise ConfigError(f"{where}: {named[0]}_body without {missing}_body; expected the poses of "
                              "both marker bodies from the bag (camera_body: T_W_Cm, board_body: "
                              "T_W_Bm)")  # fmt: skip
        export = (cfg.get("mocap") or {}).get("file")
        if "pose_streams" in cfg:
            raise ConfigError(f"{where}: camera_body and board_body, and the session also names "
                              "pose_streams; expected one motion capture: the bag's poses or the pose "
                              "streams")  # fmt: skip
        if export is not None:
            raise ConfigError(f"{where}: camera_body and board_body, and the session also names a "
                              f"motion-capture export (mocap.file: {export}); expected one motion capture: "
                              "the bag's poses or the export")  # fmt: skip
        for b in BAG_BODIES:
            spec = block[f"{b}_body"]
            out[f"{b}_body"] = {"topic": spec["topic"], "parent": spec.get("parent"),
                                "child": spec.get("child"), "time": spec.get("time", time)}  # fmt: skip
    if out["image"] is None and not named:
        raise ConfigError(f"{where}: names no topic; expected image_topic (the camera input) and/or "
                          "camera_body and board_body (the marker bodies' poses)")  # fmt: skip
    return out


def camera_poses_settings(session: str, cfg: dict) -> dict | None:
    """A session's ``camera_poses`` (a path, or ``{file, format}``) with its defaults; None without.

    Parameters
    ----------
    session : str
        Session key, for messages.
    cfg : dict
        ``config["sessions"][session]`` (validated against the schema).

    Returns
    -------
    dict or None
        ``file`` (the camera-pose stream: the camera's pose in the target frame per row, ASL,
        TUM or ETH CSV) and ``format`` (``auto`` or one of them).

    Raises
    ------
    ConfigError
        An empty path.
    """
    value = cfg.get("camera_poses")
    if value is None:
        return None
    out = {"file": value, "format": "auto"} if isinstance(value, str) else {"format": "auto", **value}
    if not out.get("file"):
        raise ConfigError(f"config: sessions.{session}.camera_poses: no file; expected the camera-pose "
                          "stream's path (camera_poses: FILE or camera_poses: {file: FILE, format: auto})")
    return out


def _camera_poses_stages(name: str, s: dict, bag: dict | None) -> tuple[str, ...]:
    """The stages of a session whose camera input is a camera-pose stream, or why it cannot run."""
    where = f"config: sessions.{name}"
    for key, why in _NOT_WITH_CAMERA_POSES.items():
        if key in s:
            raise ConfigError(f"{where}: names camera_poses and {key}; {why}")
    if bag is not None and bag["image"] is not None:
        raise ConfigError(f"{where}: names camera_poses and bag.image_topic; expected one camera input: "
                          "the camera-pose stream or the bag's image topic")  # fmt: skip
    has_mocap = "pose_streams" in s or mocap_file(s) is not None or (bag is not None and bag["camera_body"])
    if not has_mocap:
        raise ConfigError(f"{where}: names camera_poses but no motion capture of the camera's marker body; "
                          "expected pose_streams: {camera: FILE} (the camera body's poses in the mocap "
                          "world; board: FILE too when the target moves), or mocap.file with markers, or "
                          "a bag block's camera_body and board_body")  # fmt: skip
    if mocap_file(s) is not None and "markers" not in s:
        raise ConfigError(f"{where}: names a motion-capture export but no markers: expected "
                          "markers.camera.names and markers.board.names")  # fmt: skip
    logger.debug("session %s: a camera-pose stream (stages camera_poses, mocap, pose_fit)", name)
    return ("camera_poses", "mocap", "pose_fit")


def _camera_input(s: dict, bag: dict | None) -> str:
    """The session's camera input as a message names it: a video, a frame folder or a bag's topic."""
    if "frames" in s:
        return f"a frame folder ({s['frames']})"
    if bag is not None and bag["image"] is not None:
        return f"a bag's image topic ({bag['image']['topic']})"
    return f"a video ({s.get('video')})"


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
        A subset of `STAGES`, in DAG order: ``calibrate`` (own stills), ``poses`` (video or
        frame folder, and a camera), ``mocap`` (motion-capture export and markers, or pose
        streams), ``pairs`` (all of them: sync, pairs, optimisers, held-out evaluation); a
        session with ``camera_poses``: ``camera_poses`` (the stream as its poses table),
        ``mocap`` and ``pose_fit`` (sync, the pose-level fit, held-out evaluation).

    Raises
    ------
    ConfigError
        The session names a video without a camera, a Vicon export without markers, both a
        video and a frame folder or both an export and pose streams, a ``bag`` block that
        contradicts them (:func:`bag_settings`), pose streams without a board stream (but for a
        camera-pose session); a camera-pose session that names images, stills, a camera, a
        board, methods or no motion capture; or nothing to
        process; a ChArUco board without a usable marker_m or dictionary; an AprilGrid with a
        missing or invalid key.
    """
    s = sessions[name]
    where = f"config: sessions.{name}"
    if camera_poses_settings(name, s) is not None:
        return _camera_poses_stages(name, s, bag_settings(name, s))
    if "pose_streams" in s and "board" not in s["pose_streams"]:
        raise ConfigError(f"{where}.pose_streams: no board stream; expected board: FILE (the board-marker "
                          "body's poses). Only a camera_poses session may leave it out (its target static "
                          "in the mocap world)")  # fmt: skip
    if isinstance(s.get("board"), dict) and s["board"].get("type") in ("charuco", "aprilgrid"):
        try:
            if board_type(s["board"]) == "charuco":
                charuco_board(s["board"])
            else:
                aprilgrid_from_board(s["board"])
        except ConfigError as exc:
            raise ConfigError(f"{where}.{exc}") from exc
    bag = bag_settings(name, s)  # None without a bag block
    synth = "synth" in s
    cam = camera_session(name, sessions)
    for a, b, given in (("video", "frames", "video" in s), ("mocap.file", "pose_streams", mocap_file(s))):
        if given and b in s:
            raise ConfigError(f"{where}: names both {a} and {b}; expected one of the two")
    bag_image = bag is not None and bag["image"] is not None
    bag_bodies = bag is not None and bag["camera_body"] is not None
    has_video = synth or "video" in s or "frames" in s or bag_image
    has_mocap = synth or mocap_file(s) is not None or "pose_streams" in s or bag_bodies
    stages = []
    if cam == name:
        stages.append("calibrate")
    if has_video:
        if cam is None:
            raise ConfigError(
                f"{where}: names {_camera_input(s, bag)} but no calib_dir: its poses need the "
                f"camera's intrinsics. Expected calib_dir (a folder of ~15 stills of the board) "
                f"or camera: <session> to reuse the calibration of another session with the "
                f"same camera and settings"
            )
        stages.append("poses")
    if has_mocap:
        if "pose_streams" not in s and not bag_bodies and "markers" not in s:
            raise ConfigError(
                f"{where}: names a motion-capture export but no markers: expected markers.camera.names "
                f"and markers.board.names (the marker names of each rigid body in the export)"
            )
        stages.append("mocap")
    if "poses" in stages and "mocap" in stages:
        stages.append("pairs")
    if not stages:
        raise ConfigError(
            f"{where}: nothing to process; expected calib_dir, video or frames (with calib_dir or "
            f"camera), mocap.file (with markers) or pose_streams, camera_poses (with pose_streams), or a "
            f"synth block"
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


def session_methods(name: str, sessions: dict, default) -> tuple[str, ...]:
    """The optimisers session ``name`` runs: its own ``methods``, else ``optimise.methods``.

    A session whose hand or image border hides part of the board in every frame cannot be
    fitted by the seed method (it needs whole boards); ``methods: [se3]`` on that session
    alone lets the others keep both.

    Parameters
    ----------
    name : str
        Session key in ``config["sessions"]`` (after :func:`expand_rig_sessions`).
    sessions : dict
        The sessions, validated against the schema.
    default : sequence of str
        ``config["optimise"]["methods"]``.

    Returns
    -------
    tuple of str
        In the order given.
    """
    return tuple(sessions[name].get("methods", default))


def resolve_targets(sessions: dict, read_board) -> dict:
    """Sessions with their ``target`` file read into ``board``.

    A session names its board in the config (``board:``) or a Kalibr target file
    (``target: FILE``); the path is relative to the folder the workflow runs in, as
    ``calib_dir`` and ``video`` are. Every rule then sees a ``board`` block; ``target`` stays in
    the session for the record.

    Parameters
    ----------
    sessions : dict
        ``config["sessions"]``, validated against the schema.
    read_board : callable
        Path to a board block, raising a CvsflowError for a file that describes none
        (:func:`cvsflow.io.targets.read_target_board`; the workflow passes it, this module
        does no I/O).

    Returns
    -------
    dict
        Session name to its block: the same object for a session without ``target``, a copy
        with ``board`` added for one with it; in the order of ``sessions``.

    Raises
    ------
    ConfigError
        A session with both ``board`` and ``target``, or a target file that cannot be read or
        describes no cvsflow board (an unsupported target type, a missing or invalid key): the
        message names the session, the file and the key.
    """
    out = {}
    for name, s in sessions.items():
        if "target" not in s:
            out[name] = s
            continue
        where = f"config: sessions.{name}.target"
        if "board" in s:
            raise ConfigError(f"{where}: the session names a board too; expected board or target, not both")
        try:
            board = read_board(s["target"])
        except CvsflowError as exc:
            raise ConfigError(f"{where}: {exc}") from exc
        logger.debug("session %s: board %s from %s", name, board, s["target"])
        out[name] = {**s, "board": board}
    return out


def rig_camera_session(rig: str, camera: str) -> str:
    """The session name of camera ``camera`` of rig session ``rig``: ``{rig}-{camera}``.

    Parameters
    ----------
    rig : str
        Rig session key in ``config["sessions"]``.
    camera : str
        The camera's ``name`` in the rig's ``cameras`` list.

    Returns
    -------
    str
    """
    return f"{rig}-{camera}"


def expand_rig_sessions(sessions: dict) -> tuple[dict, dict]:
    """Split rig sessions (a ``cameras:`` list) into per-camera sessions and the rig's mocap.

    A rig session ``r`` with cameras ``a, b`` becomes three plain sessions, which the mono
    rules run unchanged: ``r`` (the rig's motion-capture export and markers: the mocap
    stages, bodies.parquet with the rig as the ``camera`` body) and ``r-a``, ``r-b`` (each
    camera's stills and video: calibrate, corners, poses). Rendered rigs (a ``synth`` block)
    get the paths the rig's synth rules write: ``data/r/vicon.csv``, ``data/r/<camera>/calib``,
    ``data/r/<camera>/video.mp4``, ``data/r/<camera>/shared``. Sessions without ``cameras``
    are passed through as they are, in their order.

    Parameters
    ----------
    sessions : dict
        ``config["sessions"]``, validated against the schema.

    Returns
    -------
    plain : dict
        Session name to a plain session block: the sessions without ``cameras`` (the same
        objects, in order) and each rig's sessions in its place. Equal to ``sessions`` when
        no session has ``cameras``.
    rigs : dict
        Rig name to ``{"cameras": [names], "sessions": [per-camera session names],
        "shared_dirs": [per-camera folder of shared-view stills or None], "synth": bool}``.

    Raises
    ------
    ConfigError
        A rig without markers or a Vicon export (or synth), a camera without a name, stills
        or video, repeated camera names, or a per-camera session name that is already a
        session.
    """
    plain, rigs = {}, {}
    for name, s in sessions.items():
        if "cameras" not in s:
            plain[name] = s
            continue
        where = f"config: sessions.{name}"
        synth = "synth" in s
        cams = s["cameras"]
        names = [c.get("name") for c in cams]
        if not names or not all(names) or len(set(names)) != len(names):
            raise ConfigError(f"{where}.cameras: every camera needs a distinct name, got {names}")
        if "markers" not in s:
            raise ConfigError(f"{where}: a rig needs markers.camera (the rig body) and markers.board")
        if "methods" in s:
            raise ConfigError(f"{where}.methods: a rig is fitted by optimise_se3_rig alone; "
                              "methods is for sessions with one camera")
        if not synth and mocap_file(s) is None:
            raise ConfigError(f"{where}: a rig needs its motion-capture export (mocap.file) or a synth block")
        mocap = {k: s[k] for k in ("board", "markers") if k in s}
        plain[name] = {**mocap, "mocap": {"file": f"data/{name}/vicon.csv", **(s.get("mocap") or {})}}
        entry = {"cameras": names, "sessions": [], "shared_dirs": [], "synth": synth}
        for c in cams:
            cam = rig_camera_session(name, c["name"])
            if cam in sessions:
                raise ConfigError(
                    f"{where}.cameras: camera {c['name']}'s session name {cam} is already a session")
            block = {"board": s["board"]}
            for key, leaf in (("calib_dir", "calib"), ("video", "video.mp4")):
                if key in c:
                    block[key] = c[key]
                elif synth:
                    block[key] = f"data/{name}/{c['name']}/{leaf}"
                else:
                    raise ConfigError(f"{where}.cameras[{c['name']}]: {key} is missing "
                                      f"(needed unless the rig has a synth block)")
            plain[cam] = block
            entry["sessions"].append(cam)
            shared = f"data/{name}/{c['name']}/shared" if synth else None
            entry["shared_dirs"].append(c.get("shared_dir", shared))
        rigs[name] = entry
    return plain, rigs
