"""Error statistics and the chapter's figures 1.6-1.9 for one optimiser run (rule analyse)."""

import json

from cvsflow import plots
from cvsflow.evaluate import analyse
from cvsflow.io.files import atomic_output, draw_figure, read_parquet, read_yaml
from cvsflow.io.logs import cpu_section, stage_logging
from cvsflow.plausibility import check_rows

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
        se3 = snakemake.wildcards.method == "se3"

        def marked(fig):
            return plots.results.mark_diverged(fig, diverged)

        if se3:
            draw_figure(out, "convergence", lambda: plots.se3.plot_solver_convergence(
                read_parquet(snakemake.input.iterations)))
        else:
            draw_figure(out, "convergence", lambda: plots.results.plot_convergence(
                analyse.convergence(read_parquet(snakemake.input.iterations)), result.get("f_bounds_px"),
                diverged))
        draw_figure(out, "histograms", lambda: marked(
            plots.results.plot_error_histograms(errors, analyse.normality_tests(errors))))
        draw_figure(out, "qq", lambda: marked(plots.results.plot_qq(analyse.qq_data(errors))))
        draw_figure(out, "mocap_vs_cvs", lambda: plots.results.plot_vicon_vs_cvs(
            analyse.mocap_vs_cvs(errors, result),
            plots.results.SE3_LABELS if se3 else plots.results.SEED_LABELS, diverged))
        draw_figure(out, "covariance", lambda: marked(
            plots.results.plot_covariance(*analyse.sample_error_covariance(errors))))
        draw_figure(out, "error_maps", lambda: marked(plots.results.plot_error_maps(analyse.error_maps(
            errors, bins=cfg["contour_bins"], min_count=cfg["contour_min_count"]))))
