"""CVS and Vicon poses side by side per video frame (rule pairs)."""

from cvsflow.align import make_pairs
from cvsflow.io import read_parquet, read_yaml, write_parquet
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "pairs") as log:
    pairs = make_pairs(
        read_parquet(snakemake.input.poses),
        read_parquet(snakemake.input.bodies),
        read_parquet(snakemake.input.bodies_30hz),
        read_yaml(snakemake.input.sync)["dt_offset_s"],
        resample=snakemake.params.resample,
    )
    log.info("%d pairs", len(pairs))
    write_parquet(pairs, snakemake.output[0])
