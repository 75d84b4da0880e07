"""seed and se3 side by side on held-out frames, and the calibration of the error model (rule compare)."""

import numpy as np

from cvsflow.calibration import board_object_points
from cvsflow.evaluate import compare_methods, crossfit_error_model
from cvsflow.io import read_parquet, read_yaml, save_figure, write_yaml
from cvsflow.io.logs import stage_logging
from cvsflow.plots import se3 as plots
from cvsflow.uncertainty import error_features

with stage_logging(snakemake.log[0], "compare") as log:
    ev = snakemake.params.evaluate
    seed = read_parquet(snakemake.input.seed)
    se3 = read_parquet(snakemake.input.se3)
    se3["t_s"] = se3["t_s"].astype(float)
    for d in ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad"):
        se3[f"eps_{d}"] = se3[f"err_{d}"]
    fps = 1.0 / np.median(np.diff(np.sort(se3["t_s"].to_numpy())))
    comparison = compare_methods({"seed": seed, "se3": se3},
                                 block_len=max(1, int(round(ev["boot_block_s"] * fps))),
                                 n_boot=ev["n_boot"], seed=ev["seed"])
    result = read_yaml(snakemake.input.se3_result)
    # Each fold's own parameter covariance enters the prediction: its calibration error is
    # shared by every frame it scores, and dominates the PnP corner noise.
    fits = read_yaml(snakemake.input.se3_folds)["folds"]
    features, cov_err = error_features(se3, board_object_points(snakemake.params.board),
                                       np.array(result["K"]), np.array(result["dist"]),
                                       float(np.median(se3["sigma_px"])), frame=ev["frame"],
                                       fits=fits)
    score, sigma, mu = crossfit_error_model(se3, features, cov_err)
    comparison["error_model"] = score
    comparison["error_frame"] = ev["frame"]
    log.info("se3/seed held-out RMS ratio: %s", comparison["rms_ratio_se3_to_seed"])
    log.info("error model: %.1f %% inside 68 %%, %.1f %% inside 95 %%, NEES %.2f",
             100 * score["inside_68_all"], 100 * score["inside_95_all"], score["nees_mean"])
    write_yaml(comparison, snakemake.output.comparison)
    save_figure(plots.plot_heldout_errors(se3), snakemake.output.heldout)
    save_figure(plots.plot_error_bands(se3, sigma, np.nanmean(mu, axis=0)), snakemake.output.bands)
    save_figure(plots.plot_parameter_correlation(result), snakemake.output.correlation)
