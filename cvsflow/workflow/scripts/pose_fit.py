"""Time offset, T_Cm_C and T_Bm_B from a camera-pose session's streams (rule pose_fit)."""

from cvsflow.evaluate import fit_pose_streams, pose_fit_record, stream_inputs
from cvsflow.io.files import read_parquet, read_yaml, write_yaml
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "pose_fit") as log:
    sync = read_yaml(snakemake.input.sync)
    _, *streams = stream_inputs(read_parquet(snakemake.input.poses),
                                       read_parquet(snakemake.input.bodies))
    # a stated offset (sync's method given) is held; else the fit starts at sync's (the streams'
    # own search, as handeye's), or searches again when sync found none
    given = sync["dt_offset_s"] if sync.get("method") == "given" else None
    start = sync["dt_offset_s"] if sync.get("method") == "pose_streams" else None
    res, split = fit_pose_streams(*streams, dt_offset_s=given, dt_start_s=start,
                                  offset=sync.get("details") if start is not None else None)
    record = pose_fit_record(res, split, snakemake.params.board_body)
    record["sync"] = {"dt_offset_s": sync["dt_offset_s"], "method": sync.get("method")}
    if res.dt_offset_s is not None:
        log.info("dt_offset_s = %.4f +- %.4f s (sync stage: %.4f s, %s)", res.dt_offset_s,
                 res.dt_offset_std_s, sync["dt_offset_s"], sync.get("method"))
    for what in ("dt", "hand_eye"):
        if not res.observability[what]["observable"]:
            log.warning("%s not determined: %s", what, res.observability[what]["reason"])
    write_yaml(record, snakemake.output.result)
