"""Joint SE(3) calibration: intrinsics, both marker mountings and the time offset (rule optimise_se3)."""

import numpy as np

from cvsflow.evaluate import se3_run_tables
from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.optimise import Se3Share, optimise_se3
from cvsflow.plausibility import check_se3_result

with stage_logging(snakemake.log[0], "optimise_se3") as log:
    camera = read_yaml(snakemake.input.camera)
    K_calib = camera["K"]
    sync = read_yaml(snakemake.input.sync)
    if snakemake.params.f_init_px is not None:
        K = np.array(camera["K"], dtype=float)
        K[0, 0] = K[1, 1] = snakemake.params.f_init_px
        camera["K"] = K.tolist()
    corners = read_parquet(snakemake.input.corners)
    bodies = read_parquet(snakemake.input.bodies)
    board = snakemake.params.board
    share = Se3Share(corners, bodies, board)  # tracks and PnP poses, made once for the tables
    fit = optimise_se3(corners, bodies, camera, board, sync["dt_offset_s"], share=share,
                       **snakemake.params.se3)
    for warning in fit.result.get("warnings", []):
        log.warning(warning)
    iterations, errors, result = se3_run_tables(fit, corners, bodies, board,
                                                read_parquet(snakemake.input.poses),
                                                frame=snakemake.params.frame, share=share)
    log.info("fx %.2f px, fy %.2f px, dt %.4f s, corner RMS %.3f px", result["fx_px"],
             result["fy_px"], result["dt_offset_s"], result["rms_px"])
    check_se3_result(result, K_calib, sync.get("details", {}).get("max_offset_s", 30.0),
                     f"se3 fit from {snakemake.input.corners} and {snakemake.input.bodies}")
    write_parquet(iterations, snakemake.output.iterations)
    write_parquet(errors, snakemake.output.errors)
    # wall time in the log (and benchmarks/), never in a result: the same inputs give the same file
    log.info("solved in %.2f s", result.pop("time_s", float("nan")))
    write_yaml(result, snakemake.output.result)
