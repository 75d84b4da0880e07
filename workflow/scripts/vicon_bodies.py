"""Camera and board rigid-body poses from their markers (rule vicon_bodies)."""

from cvsflow.io import read_parquet, save_figure, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.mocap import fit_bodies, resolve_layouts
from cvsflow.plausibility import check_body_fits
from cvsflow.plots import mocap as plots

with stage_logging(snakemake.log[0], "vicon_bodies") as log:
    markers = read_parquet(snakemake.input[0])
    bodies = fit_bodies(markers, snakemake.params.markers)
    log.info("valid samples: %s", bodies.groupby("body")["valid"].sum().to_dict())
    specs = resolve_layouts(markers, snakemake.params.markers)
    for warning in check_body_fits(bodies, specs, snakemake.input[0], snakemake.params.max_fit_rms_m,
                                   snakemake.params.max_fit_rms_share):
        log.warning(warning)
    write_parquet(bodies, snakemake.output.bodies)
    save_figure(plots.plot_fit_residuals(bodies), snakemake.output.fig)
