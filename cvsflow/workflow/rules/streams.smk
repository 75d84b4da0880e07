# A session whose camera input is a camera-pose stream (camera_poses): the stream is its poses
# table, then sync (rules/align.smk), the pose-level fit and its held-out evaluation.


# For such a session these rules, not rules poses and compare (whose wildcard constraints leave
# it out: NOT_CAMERA_POSES_PATTERN), write poses_raw.parquet and the held-out figures.


rule camera_poses:
    input:
        camera_poses_path,
    output:
        **figures(
            fig=report(
                "results/{session}/figures/poses_raw.png",
                caption="../report/camera_poses.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "raw poses"},
            ),
        ),
        poses="results/{session}/poses_raw.parquet",
    log:
        "logs/{session}/camera_poses.log",
    benchmark:
        "benchmarks/{session}/camera_poses.tsv"
    wildcard_constraints:
        session=CAMERA_POSES_PATTERN,
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        format=lambda wc: CAMERA_POSES[wc.session]["format"],
    script:
        "../scripts/camera_poses.py"


rule pose_fit:
    input:
        poses="results/{session}/poses_raw.parquet",
        bodies="results/{session}/bodies.parquet",
        sync="results/{session}/sync.yaml",
    output:
        result="results/{session}/pose_fit/result.yaml",
    log:
        "logs/{session}/pose_fit.log",
    benchmark:
        "benchmarks/{session}/pose_fit.tsv"
    wildcard_constraints:
        session=CAMERA_POSES_PATTERN,
    threads: 1
    resources:
        mem_mb=2000,
        runtime=20,
    params:
        board_body=lambda wc: "board"
        in SESSIONS[wc.session].get("pose_streams", {"board": 1}),
    script:
        "../scripts/pose_fit.py"


rule heldout_pose_fit:
    input:
        poses="results/{session}/poses_raw.parquet",
        bodies="results/{session}/bodies.parquet",
        sync="results/{session}/sync.yaml",
        result="results/{session}/pose_fit/result.yaml",
    output:
        **figures(
            fig_heldout=report(
                "results/{session}/figures/heldout_errors.png",
                caption="../report/heldout_pose_fit.rst",
                category="{session}",
                subcategory="held-out evaluation (pose-level fit)",
                labels={"session": "{session}", "figure": "held-out errors"},
            ),
            fig_nees=report(
                "results/{session}/figures/nees_histogram.png",
                caption="../report/pose_fit_nees.rst",
                category="{session}",
                subcategory="held-out evaluation (pose-level fit)",
                labels={"session": "{session}", "figure": "NEES histogram"},
            ),
        ),
        heldout="results/{session}/heldout/pose_fit.parquet",
        summary="results/{session}/heldout/pose_fit.yaml",
    log:
        "logs/{session}/heldout.pose_fit.log",
    benchmark:
        "benchmarks/{session}/heldout.pose_fit.tsv"
    wildcard_constraints:
        session=CAMERA_POSES_PATTERN,
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        evaluate=config["evaluate"],
    script:
        "../scripts/heldout_pose_fit.py"
