rule summary:
    input:
        unpack(summary_inputs),
    output:
        report(
            "results/summary.csv",
            caption="../report/summary.rst",
            category="Summary",
            labels={"table": "optimiser runs"},
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
