"""Time offset between the video and the Vicon take (rule sync)."""

from cvsflow import plots
from cvsflow.evaluate import stream_sync
from cvsflow.io.files import draw_figure, read_parquet, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.plausibility import check_sync_inputs
from cvsflow.sync import given_offset, synchronise

with stage_logging(snakemake.log[0], "sync") as log:
    poses = read_parquet(snakemake.input.poses)
    bodies = read_parquet(snakemake.input.bodies)
    pose_stream = getattr(snakemake.params, "pose_stream", False)  # a camera_poses session
    if not pose_stream:  # the stream fit says itself what its data cannot determine
        check_sync_inputs(poses, bodies, snakemake.params.sync.get("method", "angular_speed"),
                          snakemake.input.poses, snakemake.input.bodies)
    given = getattr(snakemake.params, "dt_offset_s", None)
    if given is not None:  # the session states it (one clock): nothing to search
        result = given_offset(poses, bodies, given)
    elif pose_stream:  # the stream fit's own search, as cvsflow handeye --camera-poses starts from
        result = stream_sync(poses, bodies, snakemake.params.sync["min_overlap_share"])
    else:
        result = synchronise(poses, bodies, **snakemake.params.sync)
    log.info("dt_offset_s = %.4f (%s, quality %s, overlap %.1f %%)", result["dt_offset_s"],
             result["method"], "n/a" if result["quality"] is None else f"{result['quality']:.2f}",
             100 * result["overlap_share"])
    write_yaml(result, snakemake.output.sync)
    draw_figure(snakemake.output, "fig", lambda: plots.mocap.plot_sync(poses, bodies, result))
