rule optimise_seed:
    input:
        pairs="results/{session}/pairs.parquet",
        corners="results/{session}/corners.parquet",
        camera="results/{session}/camera.yaml",
    output:
        iterations="results/{session}/seed/{finit}/iterations.parquet",
        errors="results/{session}/seed/{finit}/errors.parquet",
        result="results/{session}/seed/{finit}/result.yaml",
    log:
        "logs/{session}/optimise.seed.{finit}.log",
    benchmark:
        "benchmarks/{session}/optimise.seed.{finit}.tsv"
    threads: 2
    resources:
        mem_mb=3000,
        runtime=60,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        seed=config["optimise"]["seed"],
        f_init_px=lambda wc: f_init_px(wc.finit),
    script:
        "../scripts/optimise_seed.py"
