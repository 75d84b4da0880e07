"""Fill short marker gaps, optionally low-pass, flag every repaired sample (rule mocap_repair)."""

from cvsflow import plots
from cvsflow.io.files import draw_figure, read_parquet, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.mocap import repair_markers

with stage_logging(snakemake.log[0], "mocap_repair") as log:
    markers = read_parquet(snakemake.input[0])
    filled, summary = repair_markers(markers, snakemake.params.markers, snakemake.params.vicon)
    log.info("repair: %s", summary)
    write_parquet(filled, snakemake.output.markers)
    write_yaml(summary, snakemake.output.summary)
    draw_figure(snakemake.output, "fig", lambda: plots.mocap.plot_marker_gaps(filled))
