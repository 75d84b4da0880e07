"""Render one camera of a rig session: stills, shared views, video, truth (rule synth_rig_camera)."""

from pathlib import Path

from cvsflow.io.logs import stage_logging
from cvsflow.synth.render import render_rig_camera

with stage_logging(snakemake.log[0], "synth_rig_camera") as log:
    summary = render_rig_camera(snakemake.params.session, snakemake.wildcards.camera,
                                Path(snakemake.output.truth).parent)
    log.info("rendered: %s", summary)
