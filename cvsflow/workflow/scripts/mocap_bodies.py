"""Camera and board poses: fitted to their markers, as the mocap system solved them, or two pose
streams (files or a bag's topics) (rule mocap_bodies).
"""

import numpy as np

from cvsflow import plots
from cvsflow.io.files import draw_figure, read_parquet, write_parquet
from cvsflow.io.logs import stage_logging
from cvsflow.io.mocap.formats import read_pose_stream, read_system_bodies
from cvsflow.io.mocap.streams import stream_T
from cvsflow.io.rosbag_session import read_bag_body
from cvsflow.mocap import bodies_from_streams, fit_bodies, resolve_layouts
from cvsflow.plausibility import check_body_fits

with stage_logging(snakemake.log[0], "mocap_bodies") as log:
    specs = snakemake.params.markers
    bag = snakemake.params.bag
    if hasattr(snakemake.input, "camera_stream") or hasattr(snakemake.input, "bag"):  # one stream per body
        if bag is not None:  # a bag's camera_body and board_body topics
            cam, brd = read_bag_body(bag, "camera"), read_bag_body(bag, "board")
            source = f"{cam.attrs['path']} and {brd.attrs['path']}"
        else:  # pose_streams: one body per file
            fmt = snakemake.params.mocap["format"]
            cam = read_pose_stream(snakemake.input.camera_stream, fmt, given_by="pose_streams.format")
            source = str(snakemake.input.camera_stream)
            brd = None
            if hasattr(snakemake.input, "board_stream"):
                source += f" and {snakemake.input.board_stream}"
                brd = read_pose_stream(snakemake.input.board_stream, fmt, given_by="pose_streams.format")
        if brd is None:  # a camera_poses session without a board body: the target is static in W
            t_brd, T_brd = cam["t_ns"].to_numpy()[:1], np.eye(4)[None]
            log.info("no board stream: the board body is the mocap world (T_W_Bm = I)")
        else:
            t_brd, T_brd = brd["t_ns"].to_numpy(), stream_T(brd)
        bodies = bodies_from_streams(cam["t_ns"].to_numpy(), stream_T(cam), t_brd, T_brd, source=source)
        log.info("bodies from pose streams: camera %d samples (%s), board %d", len(cam),
                 cam.attrs.get("format"), len(t_brd))  # fmt: skip
        specs = {}
    elif hasattr(snakemake.input, "export"):  # mocap.bodies_from: system
        source = snakemake.input.export
        bodies = read_system_bodies(source, {b: s["system_body"] for b, s in specs.items()},
                                    snakemake.params.mocap["format"])
        log.info("bodies from the system (%s as fit_rms_m)", bodies.attrs.get("residual"))
        specs = {}
    else:
        source = snakemake.input[0]  # the repaired markers
        markers = read_parquet(source)
        # layouts resolved (learned / refined) once, for the fit and for its checks
        specs = resolve_layouts(markers, specs, refine=getattr(snakemake.params, "refine_layout", True))
        bodies = fit_bodies(markers, specs, refine_layout=False)
    log.info("valid samples: %s", bodies.groupby("body")["valid"].sum().to_dict())
    if bodies["fit_rms_m"].notna().any():  # an export may carry no residual at all
        for warning in check_body_fits(bodies, specs, source, snakemake.params.max_fit_rms_m,
                                       snakemake.params.max_fit_rms_share):
            log.warning(warning)
    write_parquet(bodies, snakemake.output.bodies)
    streams = hasattr(snakemake.input, "camera_stream")  # no marker fit to draw
    draw_figure(snakemake.output, "fig", lambda: (
        plots.mocap.plot_stream_bodies if streams else plots.mocap.plot_fit_residuals)(bodies))
