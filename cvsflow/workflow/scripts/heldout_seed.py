"""The chapter's method scored on time blocks it was not fitted on (rule heldout_seed)."""

import numpy as np

from cvsflow.evaluate import cross_validate_seed, heldout_blocks
from cvsflow.io.files import read_parquet, read_yaml, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.io.progress import Progress

with stage_logging(snakemake.log[0], "heldout_seed") as log:
    camera = read_yaml(snakemake.input.camera)
    ev = snakemake.params.evaluate
    seed_options = {**snakemake.params.seed, "k_iterations": ev["seed_k_iterations"],
                    "n_workers": snakemake.threads}
    corners = read_parquet(snakemake.input.corners)
    # the blocks heldout_se3 scores on, from the same corners: this job need not wait for it
    folds = heldout_blocks(corners, snakemake.params.board, n_folds=ev["n_folds"],
                           block_s=ev["block_s"], seed=ev["seed"])
    with Progress("heldout_seed", ev["n_folds"], "folds", log) as progress:
        heldout = cross_validate_seed(
            read_parquet(snakemake.input.pairs), corners,
            np.array(camera["K"]), np.array(camera["dist"]), snakemake.params.board,
            folds=folds, progress=progress, **seed_options,
        )
    log.info("%d held-out frames", len(heldout))
    write_parquet(heldout, snakemake.output[0])
