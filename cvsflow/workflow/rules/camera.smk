rule calibrate:
    input:
        calib_dir,
    output:
        **figures(
            fig_errors=report(
                "results/{session}/figures/calibration_errors.png",
                caption="../report/calibration_errors.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "calibration errors"},
            ),
            fig_coverage=report(
                "results/{session}/figures/calibration_coverage.png",
                caption="../report/calibration_coverage.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "calibration coverage"},
            ),
            fig_uncertainty=report(
                "results/{session}/figures/projection_uncertainty.png",
                caption="../report/projection_uncertainty.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "projection uncertainty"},
            ),
        ),
        camera="results/{session}/camera.yaml",
        corners="results/{session}/calib_corners.parquet",
        opencv="results/{session}/camera_opencv.yaml",
        kalibr="results/{session}/camchain.yaml",
        ros="results/{session}/camera_info.yaml",
    log:
        "logs/{session}/calibrate.log",
    benchmark:
        "benchmarks/{session}/calibrate.tsv"
    priority: 50
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        calibrate=config["calibrate"],
    script:
        "../scripts/calibrate.py"


rule corners:
    input:
        video_path,
    output:
        corners="results/{session}/corners.parquet",
        summary="results/{session}/corners_summary.yaml",
    log:
        "logs/{session}/corners.log",
    benchmark:
        "benchmarks/{session}/corners.tsv"
    # Snakemake's scheduler sums the priorities of the jobs it starts together: this job takes
    # both cores, so it outranks any two of the others (see the Snakefile)
    priority: 120
    threads: 2
    resources:
        mem_mb=2000,
        runtime=60,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        corners=config["corners"],
        bag=lambda wc: bag_image(wc.session),  # the frames of a bag's image topic, else None
    script:
        "../scripts/corners.py"


rule poses:
    input:
        corners="results/{session}/corners.parquet",
        camera=camera_yaml,
        calib_corners=lambda wc: camera_yaml(wc).replace(
            "camera.yaml", "calib_corners.parquet"
        ),
        video=video_path,  # its frame size is checked against the camera's
    output:
        **figures(
            fig=report(
                "results/{session}/figures/poses_raw.png",
                caption="../report/poses_raw.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "raw poses"},
            ),
            coverage=report(
                "results/{session}/figures/image_coverage.png",
                caption="../report/image_coverage.rst",
                category="{session}",
                subcategory="camera",
                labels={"session": "{session}", "figure": "image coverage"},
            ),
        ),
        poses="results/{session}/poses_raw.parquet",
    log:
        "logs/{session}/poses.log",
    benchmark:
        "benchmarks/{session}/poses.tsv"
    wildcard_constraints:
        session=NOT_CAMERA_POSES_PATTERN,
    priority: 45
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        pnp=config["pnp"],
        video=video_path,
        bag=lambda wc: bag_image(wc.session),
    script:
        "../scripts/poses.py"
