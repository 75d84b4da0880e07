"""Time offset between the video and the Vicon take (rule sync)."""

from cvsflow.align import synchronise
from cvsflow.io import read_parquet, save_figure, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.plots import mocap as plots

with stage_logging(snakemake.log[0], "sync") as log:
    poses = read_parquet(snakemake.input.poses)
    bodies = read_parquet(snakemake.input.bodies)
    result = synchronise(poses, bodies, **snakemake.params.sync)
    log.info("dt_offset_s = %.4f (%s, quality %.2f)", result["dt_offset_s"], result["method"],
             result["quality"])
    write_yaml(result, snakemake.output.sync)
    save_figure(plots.plot_sync(poses, bodies, result), snakemake.output.fig)
