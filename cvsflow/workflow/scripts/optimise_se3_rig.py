"""N cameras on one rig body fitted together: each camera's intrinsics, mounting and time
offset, the board's mounting, and the fused board poses (rule optimise_se3_rig)."""

from cvsflow.io.files import read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.rig import name_rig_result, optimise_se3_rig, rig_camera_entries, rig_fit_options

with stage_logging(snakemake.log[0], "optimise_se3_rig") as log:
    names = snakemake.params.cameras
    n = range(len(names))
    cameras = rig_camera_entries([read_parquet(snakemake.input[f"corners{k}"]) for k in n],
                                 [read_yaml(snakemake.input[f"camera{k}"]) for k in n],
                                 [read_yaml(snakemake.input[f"sync{k}"])["dt_offset_s"] for k in n])
    fit = optimise_se3_rig(cameras, read_parquet(snakemake.input.bodies), snakemake.params.board,
                           **rig_fit_options(snakemake.params.rig))
    for warning in fit.result.get("warnings", []):
        log.warning(warning)
    log.info("solved in %.2f s", fit.result.get("time_s", float("nan")))
    result = name_rig_result(fit.result, names, [snakemake.input[f"camera{k}"] for k in n])
    for c in result["cameras"]:
        log.info("%s: fx %.2f px, dt %.4f s, RMS %.3f px, %d frames", c["name"], c["K"][0][0],
                 c["dt_offset_s"], c["rms_px"], c["n_frames"])
    log.info("rig frames by number of cameras: %s", result["n_rig_frames_by_cameras"])
    write_yaml(result, snakemake.output.result)
    write_parquet(fit.errors, snakemake.output.poses)
    write_parquet(fit.iterations, snakemake.output.iterations)
