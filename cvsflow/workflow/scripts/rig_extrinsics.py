"""Each camera's pose from camera 0 from the views they took together (rule rig_extrinsics)."""

import cv2

from cvsflow.calibration import view_corners
from cvsflow.io.files import read_yaml, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.io.media import list_stills, read_gray
from cvsflow.rig import stereo_extrinsics

cv2.setNumThreads(snakemake.threads)

with stage_logging(snakemake.log[0], "rig_extrinsics") as log:
    names = snakemake.params.cameras
    tables, cameras = [], []
    for k in range(len(names)):
        paths = list_stills(snakemake.input[f"shared{k}"])
        tables.append(view_corners([(p.name, read_gray(p)) for p in paths], snakemake.params.board,
                                   snakemake.params.calibrate["subpix_window_px"]))
        cameras.append(read_yaml(snakemake.input[f"camera{k}"]))
        log.info("%s: board in %d of %d shared stills", names[k], tables[-1]["image"].nunique(), len(paths))
    rig = stereo_extrinsics(tables, cameras)
    for c in rig["cameras"]:  # cameras 1, 2, ...: their pose from camera 0
        c["name"] = names[c["camera"]]
        log.info("%s: baseline %.4f m +- %.4f m, %d shared views", c["name"], c["baseline_m"],
                 c["baseline_std_m"], c["n_shared_views"])
    write_yaml({"camera_names": list(names), **rig}, snakemake.output[0])
