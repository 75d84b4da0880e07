rule sync:
    input:
        poses="results/{session}/poses_raw.parquet",
        bodies=bodies_path,  # a rig camera's session: its rig's bodies
    output:
        **figures(
            fig=report(
                "results/{session}/figures/sync.png",
                caption="../report/sync.rst",
                category="{session}",
                subcategory="synchronisation",
                labels={"session": "{session}", "figure": "sync"},
            ),
        ),
        sync="results/{session}/sync.yaml",
    log:
        "logs/{session}/sync.log",
    benchmark:
        "benchmarks/{session}/sync.tsv"
    priority: 35
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        sync=config["sync"],
        dt_offset_s=lambda wc: session_cfg(wc.session).get("dt_offset_s"),
        # a camera_poses session's stream file (what its messages name), else ""
        pose_stream=lambda wc: (
            str(CAMERA_POSES[wc.session]["file"]) if wc.session in CAMERA_POSES else ""
        ),
    script:
        "../scripts/sync.py"


rule pairs:
    input:
        poses="results/{session}/poses_raw.parquet",
        bodies="results/{session}/bodies.parquet",
        bodies_30hz="results/{session}/bodies_30hz.parquet",
        sync="results/{session}/sync.yaml",
    output:
        "results/{session}/pairs.parquet",
    log:
        "logs/{session}/pairs.log",
    benchmark:
        "benchmarks/{session}/pairs.tsv"
    priority: 30
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        resample=lambda wc: resample_mode(wc.session),
        min_overlap_share=config["sync"]["min_overlap_share"],
    script:
        "../scripts/pairs.py"
