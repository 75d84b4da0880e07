"""Error statistics and the chapter's figures 1.6-1.9 for one optimiser run (rule analyse)."""

import json

from cvsflow.evaluate import analyse
from cvsflow.io.files import atomic_output, read_parquet, read_yaml, save_figure
from cvsflow.io.logs import cpu_section, stage_logging
from cvsflow.plausibility import check_rows
from cvsflow.plots import results as plots
from cvsflow.plots import se3 as plots_se3

with stage_logging(snakemake.log[0], "analyse") as log:
    errors = read_parquet(snakemake.input.errors)
    check_rows(errors, snakemake.input.errors, "error rows")
    result = read_yaml(snakemake.input.result)
    cfg = snakemake.params.analyse
    stats = analyse.error_statistics(errors)
    stats["optimum"] = analyse.optimum_summary(result)
    with atomic_output(snakemake.output.stats) as tmp:
        tmp.write_text(json.dumps(stats, indent=2))
    # The figures' CPU on its own line: bench/bench_pipeline.py splits the job by it.
    with cpu_section(log, "figures"):
        tests = analyse.normality_tests(errors)
        Sigma, corr = analyse.sample_error_covariance(errors)
        out = snakemake.output
        iterations = read_parquet(snakemake.input.iterations)
        # A diverged seed run (its own check) says so in every figure's title.
        diverged = result.get("diverged_reason") if result.get("diverged") else None
        if snakemake.wildcards.method == "se3":
            save_figure(plots_se3.plot_solver_convergence(iterations), out.convergence)
        else:
            conv = analyse.convergence(iterations)
            save_figure(plots.plot_convergence(conv, result.get("f_bounds_px"), diverged), out.convergence)
        save_figure(plots.mark_diverged(plots.plot_error_histograms(errors, tests), diverged), out.histograms)
        save_figure(plots.mark_diverged(plots.plot_qq(analyse.qq_data(errors)), diverged), out.qq)
        labels = plots.SE3_LABELS if snakemake.wildcards.method == "se3" else plots.SEED_LABELS
        save_figure(plots.plot_vicon_vs_cvs(analyse.mocap_vs_cvs(errors, result), labels, diverged),
                    out.mocap_vs_cvs)
        save_figure(plots.mark_diverged(plots.plot_covariance(Sigma, corr), diverged), out.covariance)
        maps = analyse.error_maps(errors, bins=cfg["contour_bins"], min_count=cfg["contour_min_count"])
        save_figure(plots.mark_diverged(plots.plot_error_maps(maps), diverged), out.error_maps)
    log.info("n = %d pairs; error norm %.4f -> %.4f m", stats["n"],
             stats["optimum"]["norm_normalised_init_m"], stats["optimum"]["norm_normalised_final_m"])
