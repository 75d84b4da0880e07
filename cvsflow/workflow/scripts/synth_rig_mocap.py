"""Render a rig session's Vicon export and every camera's truth (rule synth_rig_mocap)."""

from cvsflow.io.logs import stage_logging
from cvsflow.synth.render import render_rig_mocap

with stage_logging(snakemake.log[0], "synth_rig_mocap") as log:
    summary = render_rig_mocap(snakemake.params.session, snakemake.output.vicon, snakemake.output.truth)
    log.info("rendered: %s", summary)
