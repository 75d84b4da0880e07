rule synth:
    output:
        calib=directory("data/{session}/calib"),
        video="data/{session}/video.mp4",
        vicon="data/{session}/vicon.csv",
        truth="data/{session}/truth.yaml",
        truth_frames="data/{session}/truth_frames.parquet",
        truth_corners="data/{session}/truth_corners.parquet",
    log:
        "logs/{session}/synth.log",
    benchmark:
        "benchmarks/{session}/synth.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=30,
    params:
        session=lambda wc: session_cfg(wc.session),
    script:
        "../scripts/synth.py"
