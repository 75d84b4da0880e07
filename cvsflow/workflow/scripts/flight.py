"""A quadcopter's on-board pose error against the camera reference (rule flight)."""

import numpy as np

from cvsflow import plots
from cvsflow.board import board_object_points
from cvsflow.flight import (
    Clock,
    check_against_truth,
    corner_noise_per_axis,
    correct_rolling_shutter,
    evaluate_flight,
    factor_from_columns,
    flip_from_columns,
    reference_covariance_from_pnp,
    reference_covariance_transfer,
    reference_from_poses,
    session_error_model,
    sigma_from_columns,
)
from cvsflow.geometry import T_from_pose6
from cvsflow.io.files import draw_figure, read_parquet, read_yaml, write_parquet, write_yaml
from cvsflow.io.flightlog import read_flight_log, read_tum, write_tum
from cvsflow.io.logs import stage_logging

with stage_logging(snakemake.log[0], "flight") as log:
    cfg = snakemake.params.flight
    inp = snakemake.input
    rolling_shutter = None  # a real flight's correction, when its calibration has a line delay
    if "synth" in cfg:
        table = read_parquet(inp.reference)
        reference, Sigma_ref, flip_ref = table, sigma_from_columns(table), flip_from_columns(table)
        cal_factor = factor_from_columns(table)
        onboard = read_tum(inp.onboard)
        truth_cfg = read_yaml(inp.truth_yaml)
        T_Q_B = np.array(truth_cfg["T_Q_B"]) if cfg.get("mounting_known", True) else None
    else:
        poses = read_parquet(inp.poses)
        calib_path = inp.se3_result if hasattr(inp, "se3_result") else inp.camera
        calib = read_yaml(calib_path)
        p_B = board_object_points(snakemake.params.board)
        sigma_px = float(calib["sigma_px"]) if "sigma_px" in calib else corner_noise_per_axis(
            np.nanmedian(poses["reproj_rms_px"]), len(p_B))
        corners = read_parquet(inp.corners) if hasattr(inp, "corners") else None
        line_delay_s = float(calib.get("line_delay_s") or 0.0)
        if line_delay_s:  # docs/findings.md 2026-12-05: timed at the board's rows, shear out
            poses, shear = correct_rolling_shutter(poses, corners, p_B, calib)
            rolling_shutter = {
                "line_delay_s": line_delay_s, "from": str(calib_path),
                "shear_median_rad": float(np.nanmedian(np.linalg.norm(shear[:, 3:], axis=1))),
                "shear_median_m": float(np.nanmedian(np.linalg.norm(shear[:, :3], axis=1))),
            }  # fmt: skip
            log.info("rolling shutter: line delay %.3g s/row (%s); each frame is timed at the rows "
                     "its board covers and its predicted shear (median %.2f mrad, %.2f mm) is taken "
                     "out", line_delay_s, calib_path, 1e3 * rolling_shutter["shear_median_rad"],
                     1e3 * rolling_shutter["shear_median_m"])  # fmt: skip
        reference = reference_from_poses(poses, corners, line_delay_s)
        if corners is not None:  # model (T): seen corners, speed, residual, calibration
            model = (session_error_model(read_yaml(inp.error_model), inp.error_model)
                     if hasattr(inp, "error_model") else None)  # fmt: skip
            log.info("reference uncertainty: model (T) %s",
                     f"fitted by {inp.error_model}" if model else "fitted on the rendered sessions")
            inter_coded = bool(read_yaml(inp.corners_summary).get("inter_coded", False))
            Sigma_ref, flip_ref, cal_factor = reference_covariance_transfer(
                poses, corners, p_B, calib, model=model, inter_coded=inter_coded,
                return_terms=True, shear_corrected=bool(line_delay_s))  # fmt: skip
        else:
            Sigma_ref, flip_ref, cal_factor = reference_covariance_from_pnp(
                poses, p_B, calib["K"], calib["dist"], sigma_px), None, None
        onboard = read_flight_log(inp.onboard, cfg["format"], cfg.get("ulog_source", "local_position"),
                                  cfg.get("csv"), inp.times if hasattr(inp, "times") else None)
        T_Q_B = T_from_pose6(cfg["T_Q_B_pose6"]) if "T_Q_B_pose6" in cfg else None
    result = evaluate_flight(reference, onboard, T_Q_B, Sigma_ref,
                                alignment=cfg.get("alignment", "se3"), k_sigma=cfg.get("k_sigma", 1.0),
                             weighted_alignment=cfg.get("weighted_alignment", False),
                             flip_ref=flip_ref, cal_factor=cal_factor)
    stats = dict(result.stats)
    if rolling_shutter is not None:
        stats["rolling_shutter"] = rolling_shutter  # the correction the reference had
    if "synth" in cfg:
        truth = read_parquet(inp.truth)
        clock = Clock(**truth_cfg["clock"])
        stats["truth_check"] = check_against_truth(result, onboard, truth, np.array(truth_cfg["T_L_C"]),
                                                      clock)
        log.info("recovered minus injected error over the stated sigma, z-RMS per axis: %s "
                 "(alignment fitted to the truth: %s)", stats["truth_check"]["z_rms"],
                 stats["truth_check"].get("z_rms_truth_alignment"))
    log.info("%d pairs; APE RMSE %.4f m", stats["n_pairs"], stats["ape_trans"]["rmse"])
    write_parquet(result.errors, snakemake.output.errors)
    write_yaml(stats, snakemake.output.stats)
    write_tum(result.ref_aligned, snakemake.output.reference_tum)
    write_tum(result.est_aligned, snakemake.output.onboard_tum)
    write_tum(result.est_unaligned, snakemake.output.onboard_unaligned_tum)
    k = cfg.get("k_sigma", 1.0)
    out = snakemake.output
    draw_figure(out, "fig_errors",
                lambda: plots.flight.plot_flight_errors(result.errors, k_sigma=max(2.0, k)))
    draw_figure(out, "fig_trajectories",
                lambda: plots.flight.plot_flight_trajectories(result.ref_aligned, result.est_aligned))
    draw_figure(out, "fig_ape", lambda: plots.flight.plot_ape(result.errors, stats))
