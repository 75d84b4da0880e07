rule synth:
    output:
        calib=directory("data/{session}/calib"),
        video="data/{session}/video.mp4",
        vicon="data/{session}/vicon.csv",
        truth="data/{session}/truth.yaml",
        truth_frames="data/{session}/truth_frames.parquet",
        truth_corners="data/{session}/truth_corners.parquet",
    log:
        "logs/{session}/synth.log",
    benchmark:
        "benchmarks/{session}/synth.tsv"
    wildcard_constraints:
        session=SYNTH_PATTERN,
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        session=lambda wc: session_cfg(wc.session),
    script:
        "../scripts/synth.py"


# A rendered rig (rules/rig.smk): the mocap export with every camera's truth, and
# each camera's folder. The mono rule `synth` could also claim data/<rig>/vicon.csv.
ruleorder: synth_rig_mocap > synth


rule synth_rig_mocap:
    output:
        vicon="data/{rig}/vicon.csv",
        truth="data/{rig}/truth.yaml",
    log:
        "logs/{rig}/synth_rig_mocap.log",
    benchmark:
        "benchmarks/{rig}/synth_rig_mocap.tsv"
    wildcard_constraints:
        rig=SYNTH_RIG_PATTERN,
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        session=lambda wc: config["sessions"][wc.rig],
    script:
        "../scripts/synth_rig_mocap.py"


rule synth_rig_camera:
    output:
        calib=directory("data/{rig}/{camera}/calib"),
        shared=directory("data/{rig}/{camera}/shared"),
        video="data/{rig}/{camera}/video.mp4",
        truth="data/{rig}/{camera}/truth.yaml",
        truth_frames="data/{rig}/{camera}/truth_frames.parquet",
        truth_corners="data/{rig}/{camera}/truth_corners.parquet",
    log:
        "logs/{rig}/synth_rig_camera.{camera}.log",
    benchmark:
        "benchmarks/{rig}/synth_rig_camera.{camera}.tsv"
    wildcard_constraints:
        rig=SYNTH_RIG_PATTERN,
        camera="[A-Za-z0-9_-]+",
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        session=lambda wc: config["sessions"][wc.rig],
    script:
        "../scripts/synth_rig_camera.py"
