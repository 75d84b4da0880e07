rule flight_synth:
    output:
        reference="data/flights/{flight}/reference.parquet",
        onboard="data/flights/{flight}/onboard.tum",
        truth="data/flights/{flight}/truth.parquet",
        injected="data/flights/{flight}/injected.parquet",
        truth_yaml="data/flights/{flight}/truth.yaml",
    log:
        "logs/flights/{flight}/flight_synth.log",
    benchmark:
        "benchmarks/flights/{flight}/flight_synth.tsv"
    threads: 1
    resources:
        mem_mb=1000,
        runtime=10,
    params:
        synth=lambda wc: config["flights"][wc.flight]["synth"],
    script:
        "../scripts/flight_synth.py"


rule flight:
    input:
        unpack(flight_inputs),
    output:
        **figures(
            fig_errors=report(
                "results/flights/{flight}/figures/errors.png",
                caption="../report/flight_errors.rst",
                category="flight {flight}",
                subcategory="on-board vs camera reference",
                labels={"flight": "{flight}", "figure": "on-board error"},
            ),
            fig_trajectories=report(
                "results/flights/{flight}/figures/trajectories.png",
                caption="../report/flight_trajectories.rst",
                category="flight {flight}",
                subcategory="on-board vs camera reference",
                labels={"flight": "{flight}", "figure": "trajectories"},
            ),
            fig_ape=report(
                "results/flights/{flight}/figures/ape.png",
                caption="../report/flight_ape.rst",
                category="flight {flight}",
                subcategory="on-board vs camera reference",
                labels={"flight": "{flight}", "figure": "absolute pose error"},
            ),
        ),
        errors="results/flights/{flight}/errors.parquet",
        stats="results/flights/{flight}/stats.yaml",
        reference_tum="results/flights/{flight}/reference_aligned.tum",
        onboard_tum="results/flights/{flight}/onboard_aligned.tum",
        onboard_unaligned_tum="results/flights/{flight}/onboard_unaligned.tum",
    log:
        "logs/flights/{flight}/flight.log",
    benchmark:
        "benchmarks/flights/{flight}/flight.tsv"
    threads: 1
    resources:
        mem_mb=2000,
        runtime=15,
    params:
        flight=lambda wc: config["flights"][wc.flight],
        board=lambda wc: flight_board(wc.flight),
    script:
        "../scripts/flight.py"
