"""The rig fit scored on time blocks it was not fitted on (rule heldout_se3_rig)."""

from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.rig import cross_validate_se3_rig, heldout_scores, rig_camera_entries, rig_fit_options

with stage_logging(snakemake.log[0], "heldout_se3_rig") as log:
    n = range(len(snakemake.params.cameras))
    ev = snakemake.params.evaluate
    cameras = rig_camera_entries([read_parquet(snakemake.input[f"corners{k}"]) for k in n],
                                 [read_yaml(snakemake.input[f"camera{k}"]) for k in n],
                                 [read_yaml(snakemake.input[f"sync{k}"])["dt_offset_s"] for k in n])
    heldout, fits = cross_validate_se3_rig(
        cameras, read_parquet(snakemake.input.bodies), snakemake.params.board,
        n_folds=ev["n_folds"], block_s=ev["block_s"], seed=ev["seed"], frame=ev["frame"],
        **rig_fit_options(snakemake.params.rig),
    )
    scores = heldout_scores(heldout)
    log.info("%d held-out rig frames over %d folds: %s", len(heldout), len(fits), scores)
    # wall times in the log (and benchmarks/), never in a result: the same inputs give the same file
    log.info("fold solve times (s): %s", [fit.pop("time_s", None) for fit in fits])
    write_parquet(heldout, snakemake.output.heldout)
    write_yaml({"scores": scores, "camera_names": list(snakemake.params.cameras), "folds": fits},
               snakemake.output.folds)
