"""The chapter's focal-length and offset optimisation, eqs. 1.5-1.12 (rule optimise_seed)."""

import numpy as np

from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.optimise import optimise_seed
from cvsflow.plausibility import check_seed_result

with stage_logging(snakemake.log[0], "optimise_seed") as log:
    camera = read_yaml(snakemake.input.camera)
    f_init = snakemake.params.f_init_px
    out = optimise_seed(
        read_parquet(snakemake.input.pairs),
        read_parquet(snakemake.input.corners),
        np.array(camera["K"]),
        np.array(camera["dist"]),
        snakemake.params.board,
        f_init_px=None if f_init is None else (f_init, f_init),
        n_workers=snakemake.threads,
        **snakemake.params.seed,
    )
    log.info("fx %.2f px, fy %.2f px after %d iterations", out.result["fx_px"], out.result["fy_px"],
             out.result["iterations"])
    check_seed_result(out.result, camera["K"], f"seed fit from {snakemake.input.pairs}")
    write_parquet(out.iterations, snakemake.output.iterations)
    write_parquet(out.errors, snakemake.output.errors)
    # wall times in the log (and benchmarks/), never in a result: the same inputs give the same file
    log.info("timings (s): %s", out.result.pop("timings_s", {}))
    write_yaml(out.result, snakemake.output.result)
