"""Error statistics and the chapter's figures 1.6-1.9 for one optimiser run (rule analyse)."""

import json

from cvsflow.evaluate import analyse
from cvsflow.io.files import atomic_output, draw_figure, read_parquet, read_yaml
from cvsflow.io.logs import cpu_section, stage_logging
from cvsflow.plausibility import check_rows
from cvsflow.plots import results as plots
from cvsflow.plots import se3 as plots_se3

with stage_logging(snakemake.log[0], "analyse") as log:
    errors = read_parquet(snakemake.input.errors)
    check_rows(errors, snakemake.input.errors, "error rows")
    result = read_yaml(snakemake.input.result)
    cfg = snakemake.params.analyse
    stats = analyse.run_statistics(errors)
    stats["optimum"] = analyse.optimum_summary(result)
    with atomic_output(snakemake.output.stats) as tmp:
        tmp.write_text(json.dumps(stats, indent=2))
    log.info("n = %d pairs; error norm %.4f -> %.4f m", stats["n"],
             stats["optimum"]["norm_normalised_init_m"], stats["optimum"]["norm_normalised_final_m"])
    out = snakemake.output
    # The figures' CPU on its own line (bench/bench_pipeline.py splits the job by it); with
    # `figures: false` the rule declares none and nothing below draws.
    with cpu_section(log, "figures"):
        # A diverged seed run (its own check) says so in every figure's title.
        diverged = result.get("diverged_reason") if result.get("diverged") else None
        if snakemake.wildcards.method == "se3":
            draw_figure(out, "convergence", lambda: plots_se3.plot_solver_convergence(
                read_parquet(snakemake.input.iterations)))
        else:
            draw_figure(out, "convergence", lambda: plots.plot_convergence(
                analyse.convergence(read_parquet(snakemake.input.iterations)), result.get("f_bounds_px"),
                diverged))
        draw_figure(out, "histograms", lambda: plots.mark_diverged(
            plots.plot_error_histograms(errors, analyse.normality_tests(errors)), diverged))
        draw_figure(out, "qq", lambda: plots.mark_diverged(plots.plot_qq(analyse.qq_data(errors)), diverged))
        labels = plots.SE3_LABELS if snakemake.wildcards.method == "se3" else plots.SEED_LABELS
        draw_figure(out, "mocap_vs_cvs", lambda: plots.plot_vicon_vs_cvs(
            analyse.mocap_vs_cvs(errors, result), labels, diverged))
        draw_figure(out, "covariance", lambda: plots.mark_diverged(
            plots.plot_covariance(*analyse.sample_error_covariance(errors)), diverged))
        draw_figure(out, "error_maps", lambda: plots.mark_diverged(plots.plot_error_maps(analyse.error_maps(
            errors, bins=cfg["contour_bins"], min_count=cfg["contour_min_count"])), diverged))
