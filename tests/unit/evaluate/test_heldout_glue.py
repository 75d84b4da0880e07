"""The tables the workflow builds for the analysis and the method comparison."""

import numpy as np
import pandas as pd
import pytest

from cvsflow import metrics
from cvsflow.evaluate import heldout as ev
from cvsflow.evaluate.heldout_seed import cross_validate_seed
from cvsflow.metrics.errors import poses_from_table
from cvsflow.optimise import se3, se3_apply
from cvsflow.optimise.se3_sim import simulate_session

DIMS = ("x_m", "y_m", "z_m", "roll_rad", "pitch_rad", "yaw_rad")


@pytest.fixture(scope="module")
def session():
    return simulate_session(5, duration_s=12.0)


def _poses_raw(s):
    """poses_raw in the contract's form, from the true poses (the "original" CVS)."""
    from cvsflow.geometry.transforms import pose6_from_T

    p6 = pose6_from_T(s["truth"]["T_C_B"])
    df = pd.DataFrame(p6, columns=list(DIMS))
    df.insert(0, "frame", s["truth"]["frame"])
    return df


def _truth_pairs(s, offset=np.zeros(6)):
    """pairs.parquet of a simulated session from its true poses, P* = F - offset."""
    from scipy.spatial.transform import Rotation

    from cvsflow.geometry.transforms import pose6_from_T

    p6 = pose6_from_T(s["truth"]["T_C_B"])
    pairs = pd.DataFrame({"frame": s["truth"]["frame"], "t_s": s["truth"]["t_s"]})
    rv = Rotation.from_matrix(s["truth"]["T_C_B"][:, :3, :3]).as_rotvec()
    for j, d in enumerate(DIMS):
        pairs[f"cvs_{d}"] = p6[:, j]
        pairs[f"vic_{d}"] = p6[:, j] - offset[j]
    for j in range(3):
        pairs[f"cvs_rvec_{j}"] = rv[:, j]
    return pairs


def test_se3_run_tables_errors_equal_composed_errors_by_hand(session):
    """eps_* equal pose_errors of the same poses; vic_/cvs_ are pose6 of ref/cvs; norms are RMS."""
    s = session
    fit = se3.optimise_se3(s["corners"], s["bodies"], s["camera"], s["board"],
                           s["truth"]["dt_offset_s"] + 0.004, free=("fx", "fy"))
    iterations, errors, result = ev.se3_run_tables(fit, s["corners"], s["bodies"], s["board"],
                                                   _poses_raw(s))
    frames = se3_apply.apply_se3(fit.result, s["corners"], s["bodies"], s["board"])
    by_hand = metrics.pose_errors(poses_from_table(frames, "ref_"), poses_from_table(frames, "cvs_"))
    for d in DIMS:
        np.testing.assert_allclose(errors[f"eps_{d}"], by_hand[f"err_{d}"], atol=1e-12)
    assert result["norm_normalised_final_m"] == pytest.approx(
        np.sqrt(np.mean(by_hand["err_dist_m"] ** 2)))
    assert result["norm_normalised_init_m"] > result["norm_normalised_final_m"]
    assert result["fx_px"] == pytest.approx(np.asarray(s["truth"]["K"])[0, 0], rel=2e-3)
    assert list(iterations["iteration"]) == list(range(len(iterations)))
    assert errors["cvs_orig_x_m"].notna().all()


def test_cross_validate_seed_scores_each_frame_once_with_training_offset():
    """Every pair frame is scored once; its error is F - P* - P̄ with P̄ from the other folds,
    so on a constant-offset synthetic session the held-out error is small and near zero mean."""
    s = simulate_session(8, duration_s=12.0, pixel_noise_px=0.2)
    pairs = _truth_pairs(s, offset=np.array([0.05, -0.02, 0.1, 0.01, 0.02, -0.03]))
    folds_done = []
    held = cross_validate_seed(pairs, s["corners"], s["camera"]["K"], s["camera"]["dist"],
                                  s["board"], n_folds=3, block_s=2.0, seed=1, k_iterations=1,
                                  progress=folds_done.append)
    assert held["frame"].is_unique and len(held) == len(pairs)
    assert folds_done == [0, 1, 2, 3]
    assert set(held["fold"]) == {0, 1, 2}
    assert np.abs(held["eps_x_m"]).median() < 0.01


def test_cross_validate_seed_leaves_out_folds_without_whole_boards(caplog):
    """A hand over one corner for the first 8 s of a 12 s take (folds by 2 s block, as the
    realistic 720p render, where one fold's training held under 10 whole boards): the folds
    that cannot be fitted or scored are left out with a WARNING naming them, the rest are
    scored as before; with the hand there throughout, the error says so."""
    from cvsflow.exceptions import WholeBoardError

    s = simulate_session(8, duration_s=12.0, pixel_noise_px=0.2)
    pairs = _truth_pairs(s)
    c = s["corners"]
    hidden = (c["corner"] == 0) & (c["t_s"] < 8.0)
    args = (s["camera"]["K"], s["camera"]["dist"], s["board"])
    kw = dict(n_folds=3, block_s=2.0, seed=1, k_iterations=1)
    full = cross_validate_seed(pairs, c, *args, **kw)
    with caplog.at_level("WARNING"):
        held = cross_validate_seed(pairs, c[~hidden], *args, **kw)
    out = {0, 1, 2} - set(held["fold"])
    assert out and all(f"cross-validation fold {k} left out" in caplog.text for k in out)
    # every frame of a kept fold that shows the whole board is scored, and only those
    expect = full[full["fold"].isin(held["fold"]) & (full["t_s"] >= 8.0)]
    assert set(held["frame"]) == set(expect["frame"])
    with pytest.raises(WholeBoardError, match="no fold could be fitted") as err:
        cross_validate_seed(pairs, c[c["corner"] != 0], *args, **kw)
    # every fold named, the way out said once
    assert all(f"fold {k}: " in str(err.value) for k in range(3))
    assert str(err.value).count("run it alone") == 1
    # a fold whose blocks held 3 poses (the portrait render's 3-frame fold stopped the stage)
    few = full["frame"][full["fold"] == 0].to_numpy()[3:]
    caplog.clear()
    with caplog.at_level("WARNING"):
        held = cross_validate_seed(pairs[~pairs["frame"].isin(few)], c, *args,
                                   **{**kw, "folds": full[["t_s", "fold"]]})
    assert set(held["fold"]) == {1, 2} and "fold 0 left out: " in caplog.text
    assert "3 held-out pairs" in caplog.text


def test_crossfit_error_model_bands_on_model_data():
    """On errors drawn from the model's own form, pooled held-out band shares are near 68/95 %."""
    rng = np.random.default_rng(4)
    n = 1500
    v = rng.uniform(0.5, 2.0, (n, 6)) ** 2
    features = pd.DataFrame({f"pnp_var_{d}": v[:, j] * 1e-6 for j, d in enumerate(DIMS)})
    features["log_distance"] = np.log(rng.uniform(1, 4, n))
    features["tilt_rad"] = rng.uniform(0, 0.8, n)
    features["radius_norm"] = rng.uniform(0, 1, n)
    held = pd.DataFrame({"fold": np.repeat(np.arange(5), n // 5), "t_s": np.arange(n) / 30})
    for j, d in enumerate(DIMS):
        held[f"err_{d}"] = rng.normal(0, 1e-3 * np.sqrt(v[:, j]))
    score, sigma, mu = ev.crossfit_error_model(held, features)
    assert 0.62 < score["inside_68_all"] < 0.74
    assert 0.91 < score["inside_95_all"] < 0.98
    assert sigma.shape == (n, 6) and np.isfinite(sigma).all()


def test_compare_methods_ratio_and_rms_by_hand():
    """compare_methods gives the RMS per dimension by hand and their se3/seed ratio."""
    rng = np.random.default_rng(2)
    a = pd.DataFrame({f"eps_{d}": rng.normal(0, 1.0, 200) for d in DIMS})
    b = pd.DataFrame({f"eps_{d}": rng.normal(0, 0.1, 200) for d in DIMS})
    out = ev.compare_methods({"seed": a, "se3": b}, block_len=10, n_boot=200)
    for d in DIMS:
        rms_a = np.sqrt(np.mean(a[f"eps_{d}"] ** 2))
        assert out["seed"]["per_dim"][d]["rmse"] == pytest.approx(rms_a)
        assert out["rmse_ratio_se3_to_seed"][d] == pytest.approx(
            out["se3"]["per_dim"][d]["rmse"] / rms_a)
        lo, hi = out["seed"]["per_dim"][d]["std_lo"], out["seed"]["per_dim"][d]["std_hi"]
        assert lo < out["seed"]["per_dim"][d]["std"] < hi


def test_cross_validate_seed_takes_the_given_folds():
    """With another method's folds, each pair frame is scored in the fold of the nearest frame."""
    s = simulate_session(9, duration_s=9.0, pixel_noise_px=0.2)
    pairs = _truth_pairs(s)
    # the other method saw every other frame only, in 3 folds by thirds of the take
    other = pairs.iloc[::2][["t_s"]].copy()
    other["fold"] = np.minimum((other["t_s"] / 3.0).astype(int), 2)
    held = cross_validate_seed(pairs, s["corners"], s["camera"]["K"], s["camera"]["dist"],
                                  s["board"], folds=other, k_iterations=0)
    expected = np.minimum((held["t_s"] / 3.0 + 1e-9).astype(int), 2)
    assert (held["fold"].to_numpy() == expected.to_numpy()).mean() > 0.97


def test_seed_and_se3_are_scored_on_the_same_blocks(session):
    """heldout_blocks, from the corners alone, gives every frame se3's held-out scoring scores
    the fold it was scored in; the seed method scored on those blocks puts each of its frames
    in se3's fold of the same frame (the workflow runs the two side by side)."""
    s = session
    held_se3, _ = ev.cross_validate_se3(
        s["corners"], s["bodies"], s["camera"], s["board"], s["truth"]["dt_offset_s"],
        n_folds=3, block_s=2.0, seed=1, free=("fx", "fy"),
    )  # fmt: skip
    blocks = ev.heldout_blocks(s["corners"], s["board"], n_folds=3, block_s=2.0, seed=1)
    both = held_se3[["frame", "fold"]].merge(blocks, on="frame", suffixes=("_se3", ""))
    assert len(both) == len(held_se3) == len(blocks)
    assert (both["fold_se3"] == both["fold"]).all()
    held_seed = cross_validate_seed(_truth_pairs(s), s["corners"], s["camera"]["K"],
                                    s["camera"]["dist"], s["board"], folds=blocks, k_iterations=0)
    both = held_seed[["frame", "fold"]].merge(held_se3[["frame", "fold"]], on="frame",
                                              suffixes=("_seed", "_se3"))
    assert len(both) == len(held_seed) and set(both["fold_seed"]) == {0, 1, 2}
    assert (both["fold_seed"] == both["fold_se3"]).all()


def test_compare_methods_leaves_out_non_finite_rows():
    """A non-finite error row is left out (and counted), not turned into NaN statistics."""
    rng = np.random.default_rng(3)
    a = pd.DataFrame({f"eps_{d}": rng.normal(0, 1.0, 50) for d in DIMS})
    a.loc[7, "eps_x_m"] = np.nan
    out = ev.compare_methods({"seed": a}, block_len=5, n_boot=50)
    assert out["seed"]["n"] == 49 and np.isfinite(out["seed"]["per_dim"]["x_m"]["rmse"])


def test_diverged_seed_statistics_are_moved_and_marked():
    """A seed fold that diverged (or a held-out std over 1 m) moves seed's statistics under
    statistics_not_measurements and voids the se3/seed ratio; a sane seed is marked false."""
    rng = np.random.default_rng(3)
    sane = pd.DataFrame({f"eps_{d}": rng.normal(0, 0.01, 100) for d in DIMS})
    sane["fold"], sane["diverged"], sane["diverged_reason"] = 0, False, ""
    se3 = pd.DataFrame({f"eps_{d}": rng.normal(0, 0.001, 100) for d in DIMS})
    out = ev.mark_seed_divergence(ev.compare_methods({"seed": sane, "se3": se3}, n_boot=50), sane)
    assert out["seed"]["diverged"] is False and out["rmse_ratio_se3_to_seed"] is not None
    bad = sane.copy()
    bad.loc[bad.index[:50], ["fold", "diverged", "diverged_reason"]] = [1, True, "fy at the bound"]
    out = ev.mark_seed_divergence(ev.compare_methods({"seed": bad, "se3": se3}, n_boot=50), bad)
    assert out["seed"]["diverged"] is True and "fold 1: fy at the bound" in out["seed"]["diverged_reason"]
    assert "per_dim" not in out["seed"] and "per_dim" in out["seed"]["statistics_not_measurements"]
    assert out["rmse_ratio_se3_to_seed"] is None and out["rmse_ratio_se3_to_seed_not_measurements"]
    wide = pd.DataFrame({f"eps_{d}": rng.normal(0, 1.8, 100) for d in DIMS})
    out = ev.mark_seed_divergence(ev.compare_methods({"seed": wide, "se3": se3}, n_boot=50), wide)
    assert out["seed"]["diverged"] is True and "std" in out["seed"]["diverged_reason"]


@pytest.fixture(scope="module")
def se3_heldout(session):
    """se3's 4 held-out folds and its full fit on the session (the compare stage's inputs)."""
    s = session
    held, fits = ev.cross_validate_se3(
        s["corners"], s["bodies"], s["camera"], s["board"], s["truth"]["dt_offset_s"],
        n_folds=4, block_s=1.5, seed=0, free=["fx", "fy", "k1", "k2", "p1", "p2"],
    )  # fmt: skip
    full = se3.optimise_se3(s["corners"], s["bodies"], s["camera"], s["board"],
                            s["truth"]["dt_offset_s"]).result  # fmt: skip
    return held, fits, full


def test_compare_heldout_with_corners_scores_model_T_per_fold(session, se3_heldout):
    """With the corners, compare_heldout scores model (T) per held-out fold (the keys
    downstream tools read: error_model.folds[].nees_mean and inside_95 per axis), the model
    fitted on other sessions and the Cramer-Rao ratio; on a session of iid 0.3 px corner noise
    the held-out errors are within a factor 2 of the bound, the within-session NEES is near 6,
    and the figures build. Without the seed table the se3 half is the same."""
    import matplotlib

    matplotlib.use("Agg")
    from cvsflow.plots import uncertainty as uplots

    s = session
    held, fits, full = se3_heldout
    seed_held = held[["frame", "t_s"]].copy()
    for d in DIMS:
        seed_held[f"eps_{d}"] = held[f"err_{d}"] * 3.0
    comp, scored, sigma, mu = ev.compare_heldout(
        seed_held, held, full, fits, s["board"], n_boot=50, corners=s["corners"]
    )
    em = comp["error_model"]
    assert em["model"] == "T" and len(em["folds"]) == 4
    for f in em["folds"]:
        assert set(f["inside_95"]) == set(DIMS) and np.isfinite(f["nees_mean"])
    assert 4.0 < em["nees_mean"] < 8.5
    assert all(0.88 < v <= 1.0 for v in em["inside_95"].values())
    assert set(comp["error_model_transfer"]["inside_95"]) == set(DIMS)
    ratio = comp["cramer_rao"]["error_over_crb"]
    assert all(0.7 < v < 2.0 for v in ratio.values()), ratio
    assert sigma.shape == (len(held), 6) and np.isfinite(sigma).all()
    assert np.abs(mu).max() < 1e-9  # a global shutter: no predicted shear
    assert {"nees", "crb_x_m", "sigma_yaw_rad"} <= set(scored.columns)
    uplots.plot_calibration_table(comp)
    uplots.plot_nees_histogram(scored)
    # se3 alone (a session with methods: [se3]): no seed section, the same se3 statistics and
    # error model
    alone, scored_alone, _, _ = ev.compare_heldout(
        None, held, full, fits, s["board"], n_boot=50, corners=s["corners"]
    )
    assert "seed" in comp and "seed" not in alone and "rmse_ratio_se3_to_seed" not in alone
    assert alone["se3"] == comp["se3"] and alone["error_model"] == comp["error_model"]
    pd.testing.assert_frame_equal(scored_alone, scored)


def test_compare_heldout_fits_the_sessions_own_model_T(session, se3_heldout):
    """compare_heldout also fits model (T) on all the session's frames (error_model_fit, what
    its flights state their reference with): a maximum of the likelihood, so it explains the
    session's errors at least as well as the model fitted on the rendered sessions, and on
    iid 0.3 px corners its predicted corner noise is the generator's."""
    from cvsflow import uncertainty as un

    s = session
    held, fits, full = se3_heldout
    comp, *_ = ev.compare_heldout(None, held, full, fits, s["board"], n_boot=20,
                                  corners=s["corners"])  # fmt: skip
    model = comp["error_model_fit"]
    assert model["kind"] == "T" and model["n_train"] == len(held)
    feats = un.measurement_features(held, s["corners"], s["board"], fits=fits, frame="C")
    nll_fit = un.transfer_nll(model, feats, held)
    assert nll_fit <= un.transfer_nll(un.RENDERED_TRANSFER_MODEL, feats, held) + 1e-9
    reproj = un.corner_noise_from_reproj(feats["reproj_rms_px"].to_numpy(float),
                                         feats["n_corners"].to_numpy(float))  # fmt: skip
    sigma_px = np.sqrt(model["s0_px"] ** 2 + (model["s_reproj"] * reproj) ** 2)
    assert 0.24 < np.median(sigma_px) < 0.36, np.median(sigma_px)
