"""Chessboard corners of every video frame (rule corners)."""

import os
from functools import partial

import cv2

from cvsflow.corners import extract_corners_parallel, summarise_corners
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.frames import add_frame_ns, frame_folder_info, frame_list, iter_frames_gray
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import iter_video_gray, video_info, video_timing
from cvsflow.io.progress import Progress

# One OpenCV thread per worker process: the workers are the parallelism.
cv2.setNumThreads(1)

with stage_logging(snakemake.log[0], "corners") as log:
    video = snakemake.input[0]
    folder = os.path.isdir(video)  # a timestamped frame folder: its exact times (t_ns) kept
    info, timing = (frame_folder_info(video), None) if folder else (video_info(video), video_timing(video))
    log.info("%s %s: %s; %d processes", "frames" if folder else "video", video, info, snakemake.threads)
    with Progress("corners", info["n_frames"], "frames", log) as progress:
        corners = extract_corners_parallel(
            partial(iter_frames_gray if folder else iter_video_gray, video, undecodable=True),
            info["n_frames"],
            snakemake.params.board,
            n_workers=snakemake.threads,
            progress=progress,
            log_every=0,  # the progress line instead of each chunk's own
            subpix_window_px=snakemake.params.corners["subpix_window_px"],
            max_grid_deviation=snakemake.params.corners["max_grid_deviation"],
            restart_every=snakemake.params.corners["restart_every_frames"],
        )
    if folder:
        corners = add_frame_ns(corners, frame_list(video))
    write_parquet(corners, snakemake.output.corners)
    summary = summarise_corners(corners, timing)
    if folder:  # each image coded on its own (JPEG, PNG): no codec motion on a still board
        summary["inter_coded"] = False
    if summary["inter_coded"]:
        # docs/findings.md 2026-12-05: a still board's error there is pose-like
        log.info("%s is inter-coded (%s, %.0f %% key frames): where the board is held still its "
                 "pose errs by the codec's motion, which the corners' residual does not show; "
                 "the error model adds it (s_still). An intra-only recording (MJPEG) avoids it",
                 video, summary["codec"], 100 * summary["key_frame_share"])
    write_yaml(summary, snakemake.output.summary)
