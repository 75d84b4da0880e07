"""The pose-level fit scored on time blocks it was not fitted on (rule heldout_pose_fit)."""

from cvsflow import plots
from cvsflow.evaluate import cross_validate_streams, fold_options, heldout_summary, stream_inputs
from cvsflow.io.files import draw_figure, read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.io.progress import Progress

with stage_logging(snakemake.log[0], "heldout_pose_fit") as log:
    ev = snakemake.params.evaluate
    sync, result = read_yaml(snakemake.input.sync), read_yaml(snakemake.input.result)
    frames, *streams = stream_inputs(read_parquet(snakemake.input.poses),
                                       read_parquet(snakemake.input.bodies))
    # folds start at the full fit's offset start (no search per fold); a stated offset is held
    given = sync["dt_offset_s"] if sync.get("method") == "given" else None
    options = fold_options(result["offset"], result["dt_used_s"], given)
    with Progress("heldout_pose_fit", ev["n_folds"], "folds", log) as progress:
        heldout, fits, score = cross_validate_streams(
            frames, *streams, options, n_folds=ev["n_folds"], block_s=ev["block_s"], seed=ev["seed"],
            frame=ev["frame"], progress=progress)
    log.info("held-out: %d frames over %d folds; %.1f %% inside 68 %%, %.1f %% inside 95 %%, NEES %.2f",
             len(heldout), len(fits), 100 * score["inside_68_all"], 100 * score["inside_95_all"],
             score["nees_mean"])
    judged = score["judgement"]
    log.info("stated per-frame uncertainty against its spread with the errors' AR(1) in time (rho %s): %s%s",
             ", ".join(f"{r:.2f}" for r in judged["rho"].values()), judged["verdict"],
             f" ({'; '.join(judged['reasons'])})" if judged["reasons"] else "")
    summary = heldout_summary(heldout, fits, score, boot_block_s=ev["boot_block_s"], n_boot=ev["n_boot"],
                              seed=ev["seed"])
    write_parquet(heldout, snakemake.output.heldout)
    write_yaml(summary, snakemake.output.summary)
    draw_figure(snakemake.output, "fig_heldout", lambda: plots.se3.plot_heldout_errors(heldout))
    draw_figure(snakemake.output, "fig_nees", lambda: plots.uncertainty.plot_nees_histogram(heldout))
