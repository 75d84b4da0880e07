"""seed and se3 side by side on held-out frames, and the calibration of the error model (rule compare)."""

import numpy as np

from cvsflow import plots
from cvsflow.evaluate import compare_heldout, errors_by_view
from cvsflow.io.files import draw_figure, read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import cpu_section, stage_logging

with stage_logging(snakemake.log[0], "compare") as log:
    ev = snakemake.params.evaluate
    result = read_yaml(snakemake.input.se3_result)
    # a session that runs se3 alone (methods: [se3]) has no seed table
    inputs = dict(snakemake.input.items())
    seed = read_parquet(inputs["seed"]) if "seed" in inputs else None
    corners_summary = read_yaml(snakemake.input.corners_summary)
    if "inter_coded" not in corners_summary:
        log.warning("%s has no inter_coded (an older corners stage): the error model leaves out "
                    "the still board's codec term; snakemake --forcerun corners adds it",
                    snakemake.input.corners_summary)
    comparison, se3, sigma, mu = compare_heldout(
        seed, read_parquet(snakemake.input.se3), result,
        read_yaml(snakemake.input.se3_folds)["folds"], snakemake.params.board, frame=ev["frame"],
        boot_block_s=ev["boot_block_s"], n_boot=ev["n_boot"], seed=ev["seed"],
        corners=read_parquet(snakemake.input.corners), bodies=read_parquet(snakemake.input.bodies),
        inter_coded=bool(corners_summary.get("inter_coded", False)),
    )
    score = comparison["error_model"]
    if seed is not None:
        log.info("se3/seed held-out RMS ratio: %s", comparison["rmse_ratio_se3_to_seed"])
    log.info("error model: %.1f %% inside 68 %%, %.1f %% inside 95 %%, NEES %.2f",
             100 * score["inside_68_all"], 100 * score["inside_95_all"], score["nees_mean"])
    log.info("error model fitted on other sessions: NEES %.2f; held-out error / CRB %s",
             comparison["error_model_transfer"]["nees_mean"],
             {d: round(v, 2) for d, v in comparison["cramer_rao"]["error_over_crb"].items()})
    write_yaml(comparison, snakemake.output.comparison)
    write_parquet(se3, snakemake.output.se3_scored)
    out = snakemake.output
    with cpu_section(log, "figures"):
        draw_figure(out, "calibration_table", lambda: plots.uncertainty.plot_calibration_table(comparison))
        draw_figure(out, "nees", lambda: plots.uncertainty.plot_nees_histogram(se3))
        draw_figure(out, "heldout", lambda: plots.se3.plot_heldout_errors(se3))
        draw_figure(out, "bands", lambda: plots.se3.plot_error_bands(se3, sigma, np.nanmean(mu, axis=0)))
        draw_figure(out, "correlation", lambda: plots.se3.plot_parameter_correlation(result))
        draw_figure(out, "by_view", lambda: plots.se3.plot_errors_by_view(errors_by_view(se3)))
