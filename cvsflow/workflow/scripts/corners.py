"""Chessboard corners of every frame of a video, a frame folder or a bag's image topic (rule corners)."""

import os
from functools import partial

import cv2

from cvsflow.corners import extract_corners_parallel, summarise_corners
from cvsflow.io.files import write_parquet, write_yaml
from cvsflow.io.frames import add_frame_ns, frame_folder_info, frame_list, iter_frames_gray
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import iter_video_gray, video_info, video_timing
from cvsflow.io.progress import Progress
from cvsflow.io.rosbag_session import bag_frame_source

# One OpenCV thread per worker process: the workers are the parallelism.
cv2.setNumThreads(1)

with stage_logging(snakemake.log[0], "corners") as log:
    video, bag = snakemake.input[0], snakemake.params.bag
    frames = None  # the frame list of a frame folder or a bag: their exact times (t_ns) kept
    if bag is not None:  # a bag's image topic
        source, frames = bag_frame_source(bag)
        info, timing, what = {"n_frames": len(frames), **frames.attrs}, None, "bag"
    elif os.path.isdir(video):  # a timestamped frame folder
        source, frames = partial(iter_frames_gray, video, undecodable=True), frame_list(video)
        info, timing, what = frame_folder_info(video), None, "frames"
    else:
        source, info, timing, what = (partial(iter_video_gray, video, undecodable=True), video_info(video),
                                      video_timing(video), "video")  # fmt: skip
    log.info("%s %s: %s; %d processes", what, video, info, snakemake.threads)
    with Progress("corners", info["n_frames"], "frames", log) as progress:
        corners = extract_corners_parallel(
            source,
            info["n_frames"],
            snakemake.params.board,
            n_workers=snakemake.threads,
            progress=progress,
            log_every=0,  # the progress line instead of each chunk's own
            subpix_window_px=snakemake.params.corners["subpix_window_px"],
            max_grid_deviation=snakemake.params.corners["max_grid_deviation"],
            restart_every=snakemake.params.corners["restart_every_frames"],
        )
    if frames is not None:
        corners = add_frame_ns(corners, frames)
    write_parquet(corners, snakemake.output.corners)
    summary = summarise_corners(corners, timing)
    if frames is not None:  # each image coded on its own (raw, JPEG, PNG): no codec motion on a still board
        summary["inter_coded"] = False
    if summary["inter_coded"]:
        # docs/findings.md 2026-12-05: a still board's error there is pose-like
        log.info("%s is inter-coded (%s, %.0f %% key frames): where the board is held still its "
                 "pose errs by the codec's motion, which the corners' residual does not show; "
                 "the error model adds it (s_still). An intra-only recording (MJPEG) avoids it",
                 video, summary["codec"], 100 * summary["key_frame_share"])
    write_yaml(summary, snakemake.output.summary)
