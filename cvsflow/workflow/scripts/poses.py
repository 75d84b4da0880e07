"""Board pose per video frame (or frame of a frame folder) by RANSAC PnP + LM (rule poses)."""

import os

import cv2
import numpy as np

from cvsflow import plots
from cvsflow.calibration import estimate_poses
from cvsflow.io.files import draw_figure, read_parquet, read_yaml, write_parquet
from cvsflow.io.frames import frame_folder_info
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import video_size
from cvsflow.io.rosbag_images import bag_frames_info
from cvsflow.plausibility import check_image_size, check_poses_found

# OpenCV's own thread pool would take every core and make results differ in the last bits.
cv2.setNumThreads(snakemake.threads)

with stage_logging(snakemake.log[0], "poses") as log:
    camera = read_yaml(snakemake.input.camera)
    video, bag = snakemake.input.video, snakemake.params.bag
    # a frame folder and a bag's images have no display rotation
    if bag is not None:
        image = bag["image"]
        size = {**bag_frames_info(bag["path"], image["topic"], image["time"]), "rotation_deg": 0}
    else:
        size = {**frame_folder_info(video), "rotation_deg": 0} if os.path.isdir(video) else video_size(video)
    check_image_size(camera, size["width"], size["height"], snakemake.input.camera, snakemake.params.video,
                     size["rotation_deg"])
    corners = read_parquet(snakemake.input.corners)
    poses = estimate_poses(
        corners,
        np.array(camera["K"]),
        np.array(camera["dist"]),
        snakemake.params.board,
        **snakemake.params.pnp,
    )
    log.info("valid poses: %d of %d frames", int(poses["valid"].sum()), len(poses))
    for warning in check_poses_found(poses, corners, snakemake.params.video, snakemake.input.corners):
        log.warning(warning)
    write_parquet(poses, snakemake.output.poses)
    draw_figure(snakemake.output, "fig", lambda: plots.camera.plot_pose_timeseries(poses))
    draw_figure(snakemake.output, "coverage", lambda: plots.camera.plot_image_coverage(
        corners, read_parquet(snakemake.input.calib_corners), camera))
