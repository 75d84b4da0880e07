rule heldout_seed:
    input:
        pairs="results/{session}/pairs.parquet",
        corners="results/{session}/corners.parquet",
        camera=camera_yaml,
    output:
        "results/{session}/heldout/seed.parquet",
    log:
        "logs/{session}/heldout.seed.log",
    benchmark:
        "benchmarks/{session}/heldout.seed.tsv"
    # one thread: the two seed jobs run side by side instead (90 s demo 83.5 -> 66.3 s
    # wall, tables identical; two threads cost 28 % more CPU for 15 % less wall each)
    priority: 25
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        seed=config["optimise"]["seed"],
        evaluate=config["evaluate"],
    script:
        "../scripts/heldout_seed.py"


rule heldout_se3:
    input:
        corners="results/{session}/corners.parquet",
        bodies="results/{session}/bodies.parquet",
        camera=camera_yaml,
        sync="results/{session}/sync.yaml",
    output:
        heldout="results/{session}/heldout/se3.parquet",
        folds="results/{session}/heldout/se3_folds.yaml",
    log:
        "logs/{session}/heldout.se3.log",
    benchmark:
        "benchmarks/{session}/heldout.se3.tsv"
    priority: 20
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        se3=lambda wc: se3_settings(wc.session),
        evaluate=config["evaluate"],
    script:
        "../scripts/heldout_se3.py"


rule compare:
    input:
        unpack(compare_inputs),
        se3="results/{session}/heldout/se3.parquet",
        se3_folds="results/{session}/heldout/se3_folds.yaml",
        se3_result="results/{session}/se3/calib/result.yaml",
        corners="results/{session}/corners.parquet",
        corners_summary="results/{session}/corners_summary.yaml",
        bodies="results/{session}/bodies.parquet",
    output:
        **figures(
            heldout=report(
                "results/{session}/figures/heldout_errors.png",
                caption="../report/heldout_errors.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "held-out errors"},
            ),
            bands=report(
                "results/{session}/figures/error_bands.png",
                caption="../report/error_bands.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "predicted error bands"},
            ),
            correlation=report(
                "results/{session}/figures/se3_correlation.png",
                caption="../report/se3_correlation.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "se3 estimate correlations"},
            ),
            calibration_table=report(
                "results/{session}/figures/error_model_calibration.png",
                caption="../report/error_model_calibration.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "error model calibration"},
            ),
            nees=report(
                "results/{session}/figures/nees_histogram.png",
                caption="../report/nees_histogram.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "NEES histogram"},
            ),
            by_view=report(
                "results/{session}/figures/errors_by_view.png",
                caption="../report/errors_by_view.rst",
                category="{session}",
                subcategory="held-out comparison (seed vs se3)",
                labels={"session": "{session}", "figure": "error by distance, tilt"},
            ),
        ),
        comparison="results/{session}/comparison.yaml",
        se3_scored="results/{session}/heldout/se3_scored.parquet",
    log:
        "logs/{session}/compare.log",
    benchmark:
        "benchmarks/{session}/compare.tsv"
    wildcard_constraints:
        session=NOT_CAMERA_POSES_PATTERN,
    priority: 15
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        evaluate=config["evaluate"],
    script:
        "../scripts/compare.py"
