rule summary:
    input:
        unpack(summary_inputs),
    output:
        table=report(
            "results/summary.csv",
            caption="../report/summary.rst",
            category="Summary",
            subcategory="all sessions",
            labels={"figure": "optimiser runs (table)"},
        ),
        sweep=report(
            "results/figures/sweep.png",
            caption="../report/sweep.rst",
            category="Summary",
            subcategory="all sessions",
            labels={"figure": "focal initialisation sweep"},
        ),
        sessions=report(
            "results/figures/sessions.png",
            caption="../report/sessions.rst",
            category="Summary",
            subcategory="all sessions",
            labels={"figure": "sessions compared"},
        ),
    log:
        "logs/summary.log",
    benchmark:
        "benchmarks/summary.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=5,
    params:
        runs=lambda wc: optimiser_runs(),
    script:
        "../scripts/summary.py"


rule stage_scaling:
    input:
        table=config["analyse"].get("scaling_benchmark") or [],
    output:
        fig=report(
            "results/figures/stage_scaling.png",
            caption="../report/stage_scaling.rst",
            category="Summary",
            subcategory="pipeline cost",
            labels={"figure": "time per stage against session length"},
        ),
    log:
        "logs/stage_scaling.log",
    benchmark:
        "benchmarks/stage_scaling.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    script:
        "../scripts/stage_scaling.py"


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
        if runs_stage(session, "vicon"):
            files[f"{session}/vicon_repair"] = f"results/{session}/vicon_repair.yaml"
        if runs_stage(session, "pairs"):
            files[f"{session}/sync"] = f"results/{session}/sync.yaml"
            for method in METHODS[session]:
                # The headline reports the run from the calibrated focal lengths.
                files[f"{session}/{method}"] = f"results/{session}/{method}/calib/result.yaml"
            if "se3" in METHODS[session]:
                files[f"{session}/comparison"] = f"results/{session}/comparison.yaml"
    for flight in FLIGHTS:
        files[f"flight {flight}/stats"] = f"results/flights/{flight}/stats.yaml"
    # none in a config without a rig session: the inputs are as they were
    for rig in RIGS:
        files[f"rig {rig}/result"] = f"results/{rig}/rig/result.yaml"
        files[f"rig {rig}/heldout"] = f"results/{rig}/rig/heldout.yaml"
        if RIGS[rig]["synth"]:
            files[f"rig {rig}/truth"] = f"data/{rig}/truth.yaml"
    return files


rule headline:
    input:
        unpack(headline_inputs),
    output:
        table=report(
            "results/headline.csv",
            caption="../report/headline.rst",
            category="Summary",
            subcategory="headline numbers per session",
            labels={"figure": "headline numbers (table)"},
        ),
        rst="results/headline.rst",
    log:
        "logs/headline.log",
    benchmark:
        "benchmarks/headline.tsv"
    threads: 1
    resources:
        mem_mb=500,
        runtime=5,
    params:
        sessions=lambda wc: list(SESSIONS),
        camera_from={s: camera_session(s, SESSIONS) for s in SESSIONS},
        flights=lambda wc: list(FLIGHTS),
    script:
        "../scripts/headline.py"
