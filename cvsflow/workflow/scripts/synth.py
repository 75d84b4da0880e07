"""Render a demo session with known ground truth (rule synth)."""

from pathlib import Path

from cvsflow.io.logs import stage_logging
from cvsflow.io.progress import Progress
from cvsflow.synth.render import render_session, session_frame_count

with stage_logging(snakemake.log[0], "synth") as log:
    session = snakemake.params.session
    with Progress("synth", session_frame_count(session), "frames", log) as progress:
        summary = render_session(session, Path(snakemake.output.truth).parent, progress)
    log.info("rendered: %s", summary)
