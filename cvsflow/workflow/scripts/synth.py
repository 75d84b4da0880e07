"""Render a demo session with known ground truth (rule synth)."""

from pathlib import Path

from cvsflow.io.logs import stage_logging
from cvsflow.synth.render import render_session

with stage_logging(snakemake.log[0], "synth") as log:
    summary = render_session(snakemake.params.session, Path(snakemake.output.truth).parent)
    log.info("rendered: %s", summary)
