"""Vicon body poses at the video rate: the chapter's block mean or interpolation (rule mocap_resample)."""

import os

from cvsflow.io.files import read_parquet, write_parquet
from cvsflow.io.frames import frame_folder_info
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import video_info
from cvsflow.io.rosbag_images import bag_frames_info
from cvsflow.mocap import downsample_bodies

with stage_logging(snakemake.log[0], "mocap_resample") as log:
    video, bag = snakemake.input.video, snakemake.params.bag
    if bag is not None:  # a bag's image topic
        fps = bag_frames_info(bag["path"], bag["image"]["topic"], bag["image"]["time"])["fps"]
    else:
        fps = (frame_folder_info(video) if os.path.isdir(video) else video_info(video))["fps"]
    bodies_30hz = downsample_bodies(
        read_parquet(snakemake.input.bodies), fps, mode=snakemake.params.resample
    )
    log.info("%d samples at %.3f Hz (%s)", len(bodies_30hz), fps, snakemake.params.resample)
    write_parquet(bodies_30hz, snakemake.output[0])
