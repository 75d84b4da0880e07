"""Calibrate the camera from the stills (rule calibrate)."""

import cv2

from cvsflow import plots
from cvsflow.calibration import calibrate_camera, uncertainty_map_of
from cvsflow.io.camera_formats import write_camera_format
from cvsflow.io.files import draw_figure, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import list_stills, read_stills

# OpenCV's own thread pool would take every core and make results differ in the last bits.
cv2.setNumThreads(snakemake.threads)

with stage_logging(snakemake.log[0], "calibrate") as log:
    paths = list_stills(snakemake.input[0])
    images, unreadable = read_stills(paths)  # an empty or cut still: left out, named in camera.yaml
    camera, calib_corners = calibrate_camera(images, snakemake.params.board, **snakemake.params.calibrate,
                                             unreadable=unreadable)
    log.info("calibrated on %d of %d stills, RMS %.3f px", camera["n_used"], len(paths), camera["rms_px"])
    write_yaml(camera, snakemake.output.camera)
    write_parquet(calib_corners, snakemake.output.corners)
    # Interchange copies beside camera.yaml (OpenCV FileStorage, Kalibr camchain, ROS camera_info).
    for fmt in ("opencv", "kalibr", "ros"):
        write_camera_format(camera, fmt, snakemake.output[fmt])
    out = snakemake.output
    draw_figure(out, "fig_errors", lambda: plots.camera.plot_calibration_errors(camera))
    draw_figure(out, "fig_coverage", lambda: plots.camera.plot_calibration_coverage(calib_corners, camera))
    draw_figure(out, "fig_uncertainty", lambda: plots.camera.plot_projection_uncertainty(
        [uncertainty_map_of(camera, calib_corners, d)
         for d in (camera["projection_uncertainty"]["distance_m"], float("inf"))], camera))
    log.info("calibration verdicts: %s", camera["quality"]["summary"])
