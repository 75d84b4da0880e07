rule analyse:
    input:
        iterations="results/{session}/{method}/{finit}/iterations.parquet",
        errors="results/{session}/{method}/{finit}/errors.parquet",
        result="results/{session}/{method}/{finit}/result.yaml",
    output:
        **figures(
            convergence=analysis_figure("convergence"),
            histograms=analysis_figure("histograms"),
            qq=analysis_figure("qq"),
            mocap_vs_cvs=analysis_figure("mocap_vs_cvs"),
            covariance=analysis_figure("covariance"),
            error_maps=analysis_figure("error_maps"),
        ),
        stats="results/{session}/{method}/{finit}/stats.json",
    log:
        "logs/{session}/analyse.{method}.{finit}.log",
    benchmark:
        "benchmarks/{session}/analyse.{method}.{finit}.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        analyse=config["analyse"],
    script:
        "../scripts/analyse.py"
