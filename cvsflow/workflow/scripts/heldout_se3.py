"""The se3 calibration scored on time blocks it was not fitted on (rule heldout_se3)."""

from cvsflow.evaluate import cross_validate_se3
from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.io.progress import Progress

with stage_logging(snakemake.log[0], "heldout_se3") as log:
    ev = snakemake.params.evaluate
    with Progress("heldout_se3", ev["n_folds"], "folds", log) as progress:
        heldout, fits = cross_validate_se3(
            read_parquet(snakemake.input.corners), read_parquet(snakemake.input.bodies),
            read_yaml(snakemake.input.camera), snakemake.params.board,
            read_yaml(snakemake.input.sync)["dt_offset_s"],
            n_folds=ev["n_folds"], block_s=ev["block_s"], seed=ev["seed"], frame=ev["frame"],
            progress=progress, **snakemake.params.se3,
        )
    log.info("%d held-out frames over %d folds", len(heldout), len(fits))
    write_parquet(heldout, snakemake.output.heldout)
    # wall times in the log (and benchmarks/), never in a result: the same inputs give the same file
    log.info("fold solve times (s): %s", [fit.pop("time_s", None) for fit in fits])
    write_yaml({"folds": fits}, snakemake.output.folds)
