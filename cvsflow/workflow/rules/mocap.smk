rule mocap_import:
    input:
        mocap_path,
    output:
        markers="results/{session}/markers.parquet",
        summary="results/{session}/mocap_import.yaml",
    log:
        "logs/{session}/mocap_import.log",
    benchmark:
        "benchmarks/{session}/mocap_import.tsv"
    priority: 50
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session)["markers"],
        mocap_format=lambda wc: mocap_cfg(wc.session)["format"],
        max_scale_ratio=config["mocap"]["max_scale_ratio"],
    script:
        "../scripts/mocap_import.py"


rule mocap_repair:
    input:
        "results/{session}/markers.parquet",
    output:
        **figures(
            fig=report(
                "results/{session}/figures/mocap_markers.png",
                caption="../report/mocap_markers.rst",
                category="{session}",
                subcategory="Vicon",
                labels={"session": "{session}", "figure": "marker gaps"},
            ),
        ),
        markers="results/{session}/markers_filled.parquet",
        summary="results/{session}/mocap_repair.yaml",
    log:
        "logs/{session}/mocap_repair.log",
    benchmark:
        "benchmarks/{session}/mocap_repair.tsv"
    priority: 45
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session)["markers"],
        vicon=config["mocap"],
    script:
        "../scripts/mocap_repair.py"


rule mocap_bodies:
    input:
        unpack(mocap_bodies_input),
    output:
        **figures(
            fig=report(
                "results/{session}/figures/mocap_fit.png",
                caption="../report/mocap_fit.rst",
                category="{session}",
                subcategory="Vicon",
                labels={"session": "{session}", "figure": "rigid-body fit"},
            ),
        ),
        bodies="results/{session}/bodies.parquet",
    log:
        "logs/{session}/mocap_bodies.log",
    benchmark:
        "benchmarks/{session}/mocap_bodies.tsv"
    priority: 40
    threads: 1
    resources:
        mem_mb=2000,
        runtime=10,
    params:
        markers=lambda wc: session_cfg(wc.session).get("markers", {}),
        mocap=lambda wc: mocap_cfg(wc.session),
        max_fit_rms_m=config["mocap"]["max_fit_rms_m"],
        max_fit_rms_share=config["mocap"]["max_fit_rms_share"],
        refine_layout=config["mocap"]["refine_layout"],
        bag=lambda wc: BAGS.get(wc.session),  # the bodies' topics of a bag, else None
    script:
        "../scripts/mocap_bodies.py"


rule mocap_resample:
    input:
        bodies="results/{session}/bodies.parquet",
        video=video_path,
    output:
        "results/{session}/bodies_30hz.parquet",
    log:
        "logs/{session}/mocap_resample.log",
    benchmark:
        "benchmarks/{session}/mocap_resample.tsv"
    priority: 32
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        resample=lambda wc: resample_mode(wc.session),
        bag=lambda wc: bag_image(wc.session),
    script:
        "../scripts/mocap_resample.py"
