rule summary:
    input:
        unpack(summary_inputs),
    output:
        **figures(
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
        ),
        table=report(
            "results/summary.csv",
            caption="../report/summary.rst",
            category="Summary",
            subcategory="all sessions",
            labels={"figure": "optimiser runs (table)"},
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
