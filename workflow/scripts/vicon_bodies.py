"""Camera and board rigid-body poses from their markers (rule vicon_bodies)."""

from cvsflow.io import read_parquet, save_figure, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.mocap import fit_bodies
from cvsflow.plots import mocap as plots

with stage_logging(snakemake.log[0], "vicon_bodies") as log:
    bodies = fit_bodies(read_parquet(snakemake.input[0]), snakemake.params.markers)
    log.info("valid samples: %s", bodies.groupby("body")["valid"].sum().to_dict())
    write_parquet(bodies, snakemake.output.bodies)
    save_figure(plots.plot_fit_residuals(bodies), snakemake.output.fig)
