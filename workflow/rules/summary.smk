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
