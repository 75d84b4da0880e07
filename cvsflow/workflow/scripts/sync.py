"""Time offset between the camera (video or camera-pose stream) and the motion capture (rule sync)."""

from pathlib import Path

from cvsflow import plots
from cvsflow.io.files import draw_figure, read_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.plausibility import camera_pose_names, check_sync_inputs
from cvsflow.sync import given_offset, synchronise

with stage_logging(snakemake.log[0], "sync") as log:
    poses = read_parquet(snakemake.input.poses)
    bodies = read_parquet(snakemake.input.bodies)
    stream = getattr(snakemake.params, "pose_stream", "")  # a camera_poses session: its stream file
    if not stream:  # the stream fit says itself what its data cannot determine
        check_sync_inputs(poses, bodies, snakemake.params.sync.get("method", "angular_speed"),
                          snakemake.input.poses, snakemake.input.bodies)
    given = getattr(snakemake.params, "dt_offset_s", None)
    if given is not None:  # the session states it (one clock): nothing to search
        result = given_offset(poses, bodies, given, names=camera_pose_names(stream) if stream else None)
        if stream:
            result["camera_poses"] = stream
    elif stream:  # the stream fit's own search, as cvsflow handeye --camera-poses starts from
        # imported here: cvsflow.evaluate costs a video session's sync job 0.3 s of start-up
        from cvsflow.evaluate import stream_sync

        result = stream_sync(poses, bodies, snakemake.params.sync["min_overlap_share"], stream)
    else:
        result = synchronise(poses, bodies, **snakemake.params.sync)
    log.info("dt_offset_s = %.4f (%s, quality %s, overlap %.1f %%)", result["dt_offset_s"],
             result["method"], "n/a" if result["quality"] is None else f"{result['quality']:.2f}",
             100 * result["overlap_share"])
    write_yaml(result, snakemake.output.sync)
    labels = {"camera": f"camera poses ({Path(stream).name})", "mocap": "motion capture"} if stream else {}
    draw_figure(snakemake.output, "fig", lambda: plots.mocap.plot_sync(poses, bodies, result, **labels))
