# Sessions of two or more cameras on one camera-marker body (a `cameras:` list in a session;
# cvsflow.workflow.sessions.expand_rig_sessions). Each camera runs the mono rules as session
# `<rig>-<camera>` (calibrate, corners, poses, and sync against the rig's bodies); the rig's
# mocap runs as session `<rig>`; the rules here fit the cameras together. None of them is in
# the DAG of a config without rig sessions.


rule rig_extrinsics:
    input:
        unpack(shared_inputs),
    output:
        "results/{rig}/rig/extrinsics.yaml",
    log:
        "logs/{rig}/rig_extrinsics.log",
    benchmark:
        "benchmarks/{rig}/rig_extrinsics.tsv"
    wildcard_constraints:
        rig=RIG_PATTERN,
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        board=lambda wc: SESSIONS[wc.rig]["board"],
        cameras=lambda wc: RIGS[wc.rig]["cameras"],
        calibrate=config["calibrate"],
    script:
        "../scripts/rig_extrinsics.py"


rule optimise_se3_rig:
    input:
        unpack(rig_inputs),
    output:
        result="results/{rig}/rig/result.yaml",
        poses="results/{rig}/rig/poses.parquet",
        iterations="results/{rig}/rig/iterations.parquet",
    log:
        "logs/{rig}/optimise_se3_rig.log",
    benchmark:
        "benchmarks/{rig}/optimise_se3_rig.tsv"
    wildcard_constraints:
        rig=RIG_PATTERN,
    threads: 1
    resources:
        mem_mb=3000,
        runtime=30,
    params:
        board=lambda wc: SESSIONS[wc.rig]["board"],
        cameras=lambda wc: RIGS[wc.rig]["cameras"],
        rig=config.get("rig", {}),
    script:
        "../scripts/optimise_se3_rig.py"


rule heldout_se3_rig:
    input:
        unpack(rig_inputs),
    output:
        heldout="results/{rig}/rig/heldout.parquet",
        folds="results/{rig}/rig/heldout.yaml",
    log:
        "logs/{rig}/heldout_se3_rig.log",
    benchmark:
        "benchmarks/{rig}/heldout_se3_rig.tsv"
    wildcard_constraints:
        rig=RIG_PATTERN,
    threads: 1
    resources:
        mem_mb=3000,
        runtime=60,
    params:
        board=lambda wc: SESSIONS[wc.rig]["board"],
        cameras=lambda wc: RIGS[wc.rig]["cameras"],
        rig=config.get("rig", {}),
        evaluate=config["evaluate"],
    script:
        "../scripts/heldout_se3_rig.py"
