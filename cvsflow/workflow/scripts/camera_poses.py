"""A camera-pose stream as the session's poses table (rule camera_poses)."""

from cvsflow import plots
from cvsflow.calibration import poses_from_stream
from cvsflow.io.files import draw_figure, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.io.mocap.formats import read_pose_stream
from cvsflow.io.mocap.streams import stream_T

with stage_logging(snakemake.log[0], "camera_poses") as log:
    path = snakemake.input[0]
    stream = read_pose_stream(path, snakemake.params.format, given_by="camera_poses.format")
    log.info("%s: %d camera poses (%s)", path, len(stream), stream.attrs.get("format"))
    poses = poses_from_stream(stream["t_ns"].to_numpy(), stream_T(stream), source=path)
    write_parquet(poses, snakemake.output.poses)
    draw_figure(snakemake.output, "fig", lambda: plots.camera.plot_pose_timeseries(poses))
