rule vicon_import:
    input:
        vicon_path,
    output:
        markers="results/{session}/markers.parquet",
        summary="results/{session}/vicon_import.yaml",
    log:
        "logs/{session}/vicon_import.log",
    benchmark:
        "benchmarks/{session}/vicon_import.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session)["markers"],
        mocap_format=lambda wc: mocap_cfg(wc.session)["format"],
        max_scale_ratio=config["vicon"]["max_scale_ratio"],
    script:
        "../scripts/vicon_import.py"


rule vicon_repair:
    input:
        "results/{session}/markers.parquet",
    output:
        markers="results/{session}/markers_filled.parquet",
        summary="results/{session}/vicon_repair.yaml",
        fig=report(
            "results/{session}/figures/vicon_markers.png",
            caption="../report/vicon_markers.rst",
            category="{session}",
            subcategory="Vicon",
            labels={"session": "{session}", "figure": "marker gaps"},
        ),
    log:
        "logs/{session}/vicon_repair.log",
    benchmark:
        "benchmarks/{session}/vicon_repair.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session)["markers"],
        vicon=config["vicon"],
    script:
        "../scripts/vicon_repair.py"


rule vicon_bodies:
    input:
        unpack(vicon_bodies_input),
    output:
        bodies="results/{session}/bodies.parquet",
        fig=report(
            "results/{session}/figures/vicon_fit.png",
            caption="../report/vicon_fit.rst",
            category="{session}",
            subcategory="Vicon",
            labels={"session": "{session}", "figure": "rigid-body fit"},
        ),
    log:
        "logs/{session}/vicon_bodies.log",
    benchmark:
        "benchmarks/{session}/vicon_bodies.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session)["markers"],
        mocap=lambda wc: mocap_cfg(wc.session),
        max_fit_rms_m=config["vicon"]["max_fit_rms_m"],
        max_fit_rms_share=config["vicon"]["max_fit_rms_share"],
        refine_layout=config["vicon"]["refine_layout"],
    script:
        "../scripts/vicon_bodies.py"


rule vicon_resample:
    input:
        bodies="results/{session}/bodies.parquet",
        video=video_path,
    output:
        "results/{session}/bodies_30hz.parquet",
    log:
        "logs/{session}/vicon_resample.log",
    benchmark:
        "benchmarks/{session}/vicon_resample.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        resample=config["vicon"]["resample"],
    script:
        "../scripts/vicon_resample.py"
