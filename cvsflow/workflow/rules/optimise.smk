rule optimise_seed:
    input:
        pairs="results/{session}/pairs.parquet",
        corners="results/{session}/corners.parquet",
        camera=camera_yaml,
    output:
        iterations="results/{session}/seed/{finit}/iterations.parquet",
        errors="results/{session}/seed/{finit}/errors.parquet",
        result="results/{session}/seed/{finit}/result.yaml",
    log:
        "logs/{session}/optimise.seed.{finit}.log",
    benchmark:
        "benchmarks/{session}/optimise.seed.{finit}.tsv"
    # one thread: the two seed jobs run side by side instead (90 s demo 83.5 -> 66.3 s
    # wall, tables identical; two threads cost 28 % more CPU for 15 % less wall each)
    priority: 20
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        seed=config["optimise"]["seed"],
        f_init_px=lambda wc: f_init_px(wc.finit),
    script:
        "../scripts/optimise_seed.py"


rule optimise_se3:
    input:
        corners="results/{session}/corners.parquet",
        bodies="results/{session}/bodies.parquet",
        camera=camera_yaml,
        sync="results/{session}/sync.yaml",
        poses="results/{session}/poses_raw.parquet",
    output:
        iterations="results/{session}/se3/{finit}/iterations.parquet",
        errors="results/{session}/se3/{finit}/errors.parquet",
        result="results/{session}/se3/{finit}/result.yaml",
    log:
        "logs/{session}/optimise.se3.{finit}.log",
    benchmark:
        "benchmarks/{session}/optimise.se3.{finit}.tsv"
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        board=lambda wc: session_cfg(wc.session)["board"],
        se3=lambda wc: se3_settings(wc.session),
        frame=config["evaluate"]["frame"],
        f_init_px=lambda wc: f_init_px(wc.finit),
    script:
        "../scripts/optimise_se3.py"
