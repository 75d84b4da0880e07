"""Chessboard corners of every video frame (rule corners)."""

from cvsflow.io import write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import iter_video_gray, video_info
from cvsflow.pose import extract_corners

with stage_logging(snakemake.log[0], "corners") as log:
    info = video_info(snakemake.input[0])
    log.info("video %s: %s", snakemake.input[0], info)
    corners = extract_corners(
        iter_video_gray(snakemake.input[0]),
        snakemake.params.board,
        subpix_window_px=snakemake.params.corners["subpix_window_px"],
        n_frames=info["n_frames"],
    )
    write_parquet(corners, snakemake.output[0])
