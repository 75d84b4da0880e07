"""Render a flight: camera reference, on-board log on its own clock, and truth (rule flight_synth)."""

from pathlib import Path

from cvsflow.io.flightlog import write_flight_demo
from cvsflow.io.logs import stage_logging
from cvsflow.synth.flight_demo import render_flight

with stage_logging(snakemake.log[0], "flight_synth") as log:
    demo = render_flight(**snakemake.params.synth)
    log.info("%d video frames, %d log samples", len(demo.reference), len(demo.onboard))
    write_flight_demo(demo, Path(snakemake.output.reference).parent)
