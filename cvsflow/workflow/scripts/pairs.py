"""CVS and Vicon poses side by side per video frame (rule pairs)."""

from cvsflow.io.files import read_parquet, read_yaml, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.plausibility import check_pair_distances
from cvsflow.sync import make_pairs

with stage_logging(snakemake.log[0], "pairs") as log:
    pairs = make_pairs(
        read_parquet(snakemake.input.poses),
        read_parquet(snakemake.input.bodies),
        read_parquet(snakemake.input.bodies_30hz),
        read_yaml(snakemake.input.sync)["dt_offset_s"],
        resample=snakemake.params.resample,
        min_overlap_share=snakemake.params.min_overlap_share,
    )
    check_pair_distances(pairs, f"pairs from {snakemake.input.poses} and {snakemake.input.bodies}")
    log.info("%d pairs (%.1f %% of the video inside the take)", len(pairs),
             100 * pairs.attrs["overlap_share"])
    write_parquet(pairs, snakemake.output[0])
