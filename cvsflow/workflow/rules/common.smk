# Paths, targets and input functions only: nothing numeric lives here.
import os

from cvsflow.io.mocap.formats import mocap_settings
from cvsflow.io.trajectory import kitti_times_path
from cvsflow.io.targets import read_target_board
from cvsflow.workflow.sessions import (
    bag_settings,
    camera_poses_settings,
    camera_session,
    check_sessions,
    expand_rig_sessions,
    resolve_targets,
    session_methods,
)


wildcard_constraints:
    session="[A-Za-z0-9_-]+",


# A rig session (a `cameras:` list) runs as plain sessions: its mocap (`<rig>`) and one per
# camera (`<rig>-<camera>`); RIGS holds what the rig rules (cvsflow/workflow/rules/rig.smk) need.
# Without rig sessions SESSIONS is config["sessions"] itself and RIGS is empty. A session's
# `target:` (a Kalibr target file, relative to the working directory) is read into its board here.
SESSIONS, RIGS = expand_rig_sessions(
    resolve_targets(config["sessions"], read_target_board)
)
# The rig's name in the rig rules' wildcards (rendered rigs: the synth rules'); both match
# nothing without rig sessions.
RIG_PATTERN = "|".join(RIGS) if RIGS else "(?!x)x"
SYNTH_RIG_PATTERN = "|".join(r for r in RIGS if RIGS[r]["synth"]) or "(?!x)x"
# Sessions the synth rule renders; a real session's files under data/<name>/ are read where
# they are, whatever <name> is.
SYNTH_PATTERN = "|".join(s for s in SESSIONS if "synth" in SESSIONS[s]) or "(?!x)x"
# camera session -> its rig
RIG_OF_CAMERA = {cam: rig for rig, r in RIGS.items() for cam in r["sessions"]}
# What each session runs; a session naming an input it cannot use stops here, before any job.
SESSION_STAGES = check_sessions(SESSIONS)
# The optimisers each session runs: its own methods, else optimise.methods.
METHODS = {
    s: session_methods(s, SESSIONS, config["optimise"]["methods"]) for s in SESSIONS
}


# A session's ROS bag block (cvsflow.io.rosbag_session): its image topic is the camera input,
# its two body topics the motion capture.
BAGS = {s: bag_settings(s, SESSIONS[s]) for s in SESSIONS if "bag" in SESSIONS[s]}


def bag_image(session):
    """The session's bag settings when its camera input is a bag's image topic, else None."""
    bag = BAGS.get(session)
    return bag if bag is not None and bag["image"] is not None else None


def _mocap(s):
    """How a session's motion capture is read: two pose streams (files or a bag's topics:
    bodies_from streams) or an export (mocap_settings, checked here, at parse time)."""
    if "pose_streams" in SESSIONS[s]:
        return {
            "format": SESSIONS[s]["pose_streams"].get("format", "auto"),
            "bodies_from": "streams",
        }
    if s in BAGS and BAGS[s]["camera_body"] is not None:
        return {"format": "rosbag", "bodies_from": "streams"}
    return mocap_settings(s, SESSIONS[s])


MOCAP = {s: _mocap(s) for s in SESSIONS if "mocap" in SESSION_STAGES[s]}


def figures(**outputs):
    """A rule's figure outputs, or none when the config says `figures: false` (a sweep): the
    jobs then neither draw nor save them."""
    return outputs if config["figures"] else {}


def session_cfg(session):
    return SESSIONS[session]


def mocap_cfg(session):
    return MOCAP[session]


def bodies_path(wildcards):
    """bodies.parquet of the session, or of its rig for a rig camera's session."""
    return f"results/{RIG_OF_CAMERA.get(wildcards.session, wildcards.session)}/bodies.parquet"


def mocap_bodies_input(wildcards):
    """The repaired markers, the export itself (the system's own body poses), or the pose streams."""
    if MOCAP[wildcards.session]["format"] == "rosbag":
        return {"bag": BAGS[wildcards.session]["path"]}
    if MOCAP[wildcards.session]["bodies_from"] == "streams":
        streams = SESSIONS[wildcards.session]["pose_streams"]
        files = {"camera_stream": streams["camera"]}
        # a camera_poses session's target may be static in the world: no board stream
        if "board" in streams:
            files["board_stream"] = streams["board"]
        return files
    if MOCAP[wildcards.session]["bodies_from"] == "system":
        return {"export": mocap_path(wildcards)}
    return {"markers": f"results/{wildcards.session}/markers_filled.parquet"}


def is_synth(session):
    return "synth" in SESSIONS[session]


def _session_path(session, key, synth_name):
    """The user's path (key `a.b` for a nested one), or where the synth rule renders it for a
    rendered session."""
    s = SESSIONS[session]
    if "synth" in s:
        return f"data/{session}/{synth_name}"
    value = s
    for part in key.split("."):
        value = value.get(part) if isinstance(value, dict) else None
    if value is None:
        raise ValueError(
            f"config: sessions.{session}.{key} is missing (a path is needed unless the "
            f"session has a synth block)"
        )
    return value


def calib_dir(wildcards):
    return _session_path(wildcards.session, "calib_dir", "calib")


def video_path(wildcards):
    """The session's video, its timestamped frame folder (frames), or its bag (the image topic's)."""
    if bag_image(wildcards.session) is not None:
        return bag_image(wildcards.session)["path"]
    if "frames" in SESSIONS[wildcards.session]:
        return SESSIONS[wildcards.session]["frames"]
    return _session_path(wildcards.session, "video", "video.mp4")


def resample_mode(session):
    """mocap.resample, or interp for a frame folder or a bag's frames (irregular frame times: each
    frame's own time)."""
    if "frames" in SESSIONS[session] or bag_image(session) is not None:
        return "interp"
    return config["mocap"]["resample"]


def se3_settings(session):
    """optimise.se3, with the time offset held where the session states it (dt_offset_s)."""
    if "dt_offset_s" in SESSIONS[session]:
        return {**config["optimise"]["se3"], "fit_dt": False}
    return config["optimise"]["se3"]


def mocap_path(wildcards):
    return _session_path(wildcards.session, "mocap.file", "vicon.csv")


def camera_yaml(wildcards):
    """The session's own camera.yaml, or that of the session its `camera` key names."""
    return f"results/{camera_session(wildcards.session, SESSIONS)}/camera.yaml"


def runs_stage(session, stage):
    return stage in SESSION_STAGES[session]


# Sessions whose camera input is a camera-pose stream: their poses table is the stream's
# (rule camera_poses, cvsflow/workflow/rules/streams.smk), not the poses rule's.
CAMERA_POSES = {
    s: camera_poses_settings(s, SESSIONS[s])
    for s in SESSIONS
    if runs_stage(s, "camera_poses")
}
CAMERA_POSES_PATTERN = "|".join(CAMERA_POSES) or "(?!x)x"
# Every other session (rules poses and compare: their outputs' names are a camera-pose
# session's too, and their inputs (corners, a video) it has not)
NOT_CAMERA_POSES_PATTERN = f"(?!(?:{CAMERA_POSES_PATTERN})(?:/|$))[A-Za-z0-9_-]+"


def camera_poses_path(wildcards):
    return CAMERA_POSES[wildcards.session]["file"]


def pose_fit_targets(session):
    """The outputs of a camera-pose session's sync, pose-level fit and held-out evaluation."""
    base = f"results/{session}"
    return [
        f"{base}/poses_raw.parquet",
        f"{base}/figures/poses_raw.png",
        f"{base}/bodies.parquet",
        f"{base}/sync.yaml",
        f"{base}/figures/sync.png",
        f"{base}/pose_fit/result.yaml",
        f"{base}/heldout/pose_fit.parquet",
        f"{base}/heldout/pose_fit.yaml",
        f"{base}/figures/heldout_errors.png",
        f"{base}/figures/nees_histogram.png",
    ]


def session_targets(session):
    if runs_stage(session, "pose_fit"):
        return pose_fit_targets(session)
    out = []
    if runs_stage(session, "calibrate"):
        out += [
            f"results/{session}/camera.yaml",
            f"results/{session}/figures/calibration_errors.png",
            f"results/{session}/figures/calibration_coverage.png",
            f"results/{session}/figures/projection_uncertainty.png",
        ]
    if runs_stage(session, "poses"):
        out += [
            f"results/{session}/poses_raw.parquet",
            f"results/{session}/figures/poses_raw.png",
        ]
    if runs_stage(session, "mocap"):
        # A rig's mocap session has no video of its own to resample at.
        out.append(
            f"results/{session}/bodies_30hz.parquet"
            if runs_stage(session, "poses")
            else f"results/{session}/bodies.parquet"
        )
        if MOCAP[session]["bodies_from"] == "markers":
            out.append(f"results/{session}/figures/mocap_markers.png")
    if runs_stage(session, "pairs"):
        out += [
            f"results/{session}/sync.yaml",
            f"results/{session}/pairs.parquet",
            f"results/{session}/figures/sync.png",
        ]
        out += optimiser_targets(session)
        if "se3" in METHODS[session]:
            out.append(f"results/{session}/comparison.yaml")
    return out


def all_targets():
    targets = [t for s in SESSIONS for t in session_targets(s)]
    if optimiser_runs():
        targets.append("results/summary.csv")
    # The report's landing page shows this table (cvsflow/workflow/report/workflow.rst).
    targets.append("results/headline.csv")
    # bench/bench_scaling.py's table, drawn when the config names one that exists
    scaling = config["analyse"].get("scaling_benchmark")
    if scaling and os.path.isfile(scaling):
        targets.append("results/figures/stage_scaling.png")
    targets += flight_targets() + rig_targets()
    # `figures: false`: no rule declares its figures (see figures()), so none is a target
    return (
        targets if config["figures"] else [t for t in targets if "/figures/" not in t]
    )


wildcard_constraints:
    method="seed|se3",
    finit="calib|[0-9]+(\.[0-9]+)?",


def finit_label(value):
    """Wildcard value of a focal initialisation: 'calib' or the px value without trailing zeros."""
    return "calib" if value == "calib" else f"{float(value):g}"


def f_init_px(finit):
    return None if finit == "calib" else float(finit)


def analysis_figure(name):
    return report(
        f"results/{{session}}/{{method}}/{{finit}}/figures/{name}.png",
        caption=f"../report/{name}.rst",
        category="{session}",
        subcategory="errors: {method}, f_init {finit}",
        labels={
            "session": "{session}",
            "method": "{method}",
            "f_init": "{finit}",
            "figure": name,
        },
    )


def optimiser_targets(session):
    out = []
    for method in METHODS[session]:
        for value in config["optimise"]["f_init"]:
            base = f"results/{session}/{method}/{finit_label(value)}"
            out += [f"{base}/result.yaml", f"{base}/stats.json"]
    return out


def optimiser_runs():
    """(session, method, finit) of every optimiser run the config asks for."""
    runs = []
    for session in SESSIONS:
        if runs_stage(session, "pairs"):
            for method in METHODS[session]:
                for value in config["optimise"]["f_init"]:
                    runs.append((session, method, finit_label(value)))
    return runs


def summary_inputs(wildcards):
    files = {}
    for session, method, finit in optimiser_runs():
        base = f"results/{session}/{method}/{finit}"
        files[f"{session}/{method}/{finit}/result"] = f"{base}/result.yaml"
        files[f"{session}/{method}/{finit}/stats"] = f"{base}/stats.json"
        files[f"{session}/pairs"] = f"results/{session}/pairs.parquet"
        if is_synth(session):
            files[f"{session}/truth"] = f"data/{session}/truth.yaml"
            files[f"{session}/truth_frames"] = f"data/{session}/truth_frames.parquet"
    return files


FLIGHTS = config.get("flights", {})


wildcard_constraints:
    flight="[A-Za-z0-9_-]+",


def flight_inputs(wildcards):
    """A rendered flight's files, or a real flight's log and its camera session's tables."""
    f = FLIGHTS[wildcards.flight]
    if "synth" in f:
        base = f"data/flights/{wildcards.flight}"
        return {
            "reference": f"{base}/reference.parquet",
            "onboard": f"{base}/onboard.tum",
            "truth": f"{base}/truth.parquet",
            "truth_yaml": f"{base}/truth.yaml",
        }
    s = f["session"]
    files = {
        "onboard": f["log"],
        "poses": f"results/{s}/poses_raw.parquet",
        "camera": f"results/{s}/camera.yaml",
        "corners": f"results/{s}/corners.parquet",  # the reference's error model (T)
    }
    files["corners_summary"] = f"results/{s}/corners_summary.yaml"  # inter-coded video
    # KITTI poses carry no times: their file is an input too
    if f.get("format") == "kitti":
        files["times"] = f.get("times") or str(kitti_times_path(f["log"]))
    if "calibration" in f:
        files["se3_result"] = f"results/{f['calibration']}/se3/calib/result.yaml"
        if f.get("error_model", "session") == "session":
            # model (T) as the validation session fitted it on its held-out frames
            files["error_model"] = f"results/{f['calibration']}/comparison.yaml"
    return files


def flight_board(flight):
    f = FLIGHTS[flight]
    return None if "synth" in f else SESSIONS[f["session"]]["board"]


def flight_targets():
    return [
        f"results/flights/{name}/{leaf}"
        for name in FLIGHTS
        for leaf in ("stats.yaml", "figures/errors.png", "onboard_aligned.tum")
    ]


# Inputs of the evaluate rules
def compare_inputs(wildcards):
    """se3's held-out table, and the seed method's when the session runs it."""
    if "seed" in METHODS[wildcards.session]:
        return {"seed": f"results/{wildcards.session}/heldout/seed.parquet"}
    return {}


# Inputs of the summary rules
def headline_inputs(wildcards):
    """Per session the files the headline table reads (only those its stages write)."""
    files = {}
    for session in SESSIONS:
        cam = camera_session(session, SESSIONS)
        if cam is not None and (cam != session or runs_stage(session, "calibrate")):
            files[f"{session}/camera"] = f"results/{cam}/camera.yaml"
        if is_synth(session):
            files[f"{session}/truth"] = f"data/{session}/truth.yaml"
        if runs_stage(session, "poses"):
            files[f"{session}/corners"] = f"results/{session}/corners_summary.yaml"
        if runs_stage(session, "mocap") and MOCAP[session]["bodies_from"] == "markers":
            files[f"{session}/mocap_import"] = f"results/{session}/mocap_import.yaml"
        if runs_stage(session, "mocap") and MOCAP[session]["bodies_from"] != "streams":
            files[f"{session}/mocap_repair"] = f"results/{session}/mocap_repair.yaml"
        if runs_stage(session, "pose_fit"):
            files[f"{session}/sync"] = f"results/{session}/sync.yaml"
            files[f"{session}/pose_fit"] = f"results/{session}/pose_fit/result.yaml"
            files[f"{session}/pose_fit_heldout"] = (
                f"results/{session}/heldout/pose_fit.yaml"
            )
        if runs_stage(session, "pairs"):
            files[f"{session}/sync"] = f"results/{session}/sync.yaml"
            for method in METHODS[session]:
                # The headline reports the run from the calibrated focal lengths.
                files[f"{session}/{method}"] = (
                    f"results/{session}/{method}/calib/result.yaml"
                )
            if "se3" in METHODS[session]:
                files[f"{session}/comparison"] = f"results/{session}/comparison.yaml"
                # the verdict's distance and figure (outputs of the jobs comparison.yaml needs)
                files[f"{session}/heldout"] = f"results/{session}/heldout/se3.parquet"
                if config["figures"]:
                    files[f"{session}/bands"] = (
                        f"results/{session}/figures/error_bands.png"
                    )
    for flight in FLIGHTS:
        files[f"flight {flight}/stats"] = f"results/flights/{flight}/stats.yaml"
        if config["figures"]:
            files[f"flight {flight}/errors"] = (
                f"results/flights/{flight}/figures/errors.png"
            )
    # none in a config without a rig session: the inputs are as they were
    for rig in RIGS:
        files[f"rig {rig}/result"] = f"results/{rig}/rig/result.yaml"
        files[f"rig {rig}/heldout"] = f"results/{rig}/rig/heldout.yaml"
        if RIGS[rig]["synth"]:
            files[f"rig {rig}/truth"] = f"data/{rig}/truth.yaml"
    return files


# Inputs and targets of the rig rules (none is called without rig sessions)
def rig_inputs(wildcards):
    """Per camera its corners, camera.yaml and sync.yaml; the rig's bodies."""
    files = {"bodies": f"results/{wildcards.rig}/bodies.parquet"}
    for k, s in enumerate(RIGS[wildcards.rig]["sessions"]):
        files[f"corners{k}"] = f"results/{s}/corners.parquet"
        files[f"camera{k}"] = f"results/{s}/camera.yaml"
        files[f"sync{k}"] = f"results/{s}/sync.yaml"
    return files


def shared_inputs(wildcards):
    """Per camera its shared-view stills and camera.yaml."""
    r = RIGS[wildcards.rig]
    files = {}
    for k, (s, d) in enumerate(zip(r["sessions"], r["shared_dirs"])):
        files[f"shared{k}"] = d
        files[f"camera{k}"] = f"results/{s}/camera.yaml"
    return files


def rig_targets():
    out = []
    for rig, r in RIGS.items():
        out += [f"results/{s}/sync.yaml" for s in r["sessions"]]
        out += [
            f"results/{rig}/rig/{leaf}"
            for leaf in (
                "result.yaml",
                "poses.parquet",
                "heldout.parquet",
                "heldout.yaml",
            )
        ]
        if len(r["cameras"]) > 1 and all(r["shared_dirs"]):
            out.append(f"results/{rig}/rig/extrinsics.yaml")
    return out
