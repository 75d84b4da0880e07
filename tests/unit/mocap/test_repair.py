"""Marker gap repair and the low-pass filter (rule mocap_repair) against synthetic truth."""

import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import MocapError
from cvsflow.mocap.bodies import fit_bodies
from cvsflow.mocap.repair import fill_marker_gaps, lowpass_markers, repair_markers
from tests.helpers.mocap_markers import RATE_HZ, body_specs, synthetic_markers


def test_rigid_fill_is_exact_and_flagged():
    """A one-marker gap with three markers measured is filled from the rigid body (exact without
    noise), flagged, counted as rigid, and measured samples are left untouched."""
    df, _, _ = synthetic_markers(duration_s=2.0)
    truth = df.copy()
    cols = [f"board:B2_{a}_m" for a in "xyz"]
    df.loc[100:159, cols] = np.nan  # 0.2 s: longer than max_gap_s, rigid fill still applies
    filled, summary = fill_marker_gaps(df, body_specs(), max_gap_s=0.1)
    np.testing.assert_allclose(filled[cols].to_numpy(), truth[cols].to_numpy(), atol=1e-9)
    flags = filled["board:B2_filled"].to_numpy()
    assert flags[100:160].all() and flags.sum() == 60
    assert summary["per_marker"]["board:B2"] == {"measured": 540, "rigid": 60, "interp": 0, "missing": 0}
    assert not filled["board:B1_filled"].any()
    np.testing.assert_array_equal(filled["board:B1_x_m"], truth["board:B1_x_m"])


def test_repair_summary_warns_of_markers_never_seen_and_long_gaps():
    """mocap_repair.yaml's ``warnings``: none on a clean take; a marker never measured (here
    refilled from its body every sample) is named; over 20 % of the samples missing is counted."""
    df, _, _ = synthetic_markers(duration_s=2.0)
    assert fill_marker_gaps(df, body_specs(), max_gap_s=0.1)[1]["warnings"] == []
    bad = df.copy()
    bad[[f"board:B2_{a}_m" for a in "xyz"]] = np.nan
    for n in ("camera:C1", "camera:C2"):
        bad.loc[: len(bad) // 2, [f"{n}_{a}_m" for a in "xyz"]] = np.nan
    _, summary = fill_marker_gaps(bad, body_specs(), max_gap_s=0.1)
    text = " | ".join(summary["warnings"])
    assert "markers ['board:B2'] never measured in 600 samples" in text
    camera_gone = df.copy()
    for n in ("camera:C1", "camera:C2", "camera:C3"):
        camera_gone[[f"{n}_{a}_m" for a in "xyz"]] = np.nan
    text = " | ".join(fill_marker_gaps(camera_gone, body_specs(), max_gap_s=0.1)[1]["warnings"])
    assert "1800 of 4800 marker samples (37.5 %) stay missing" in text


def test_interpolation_fill_short_gaps_within_1mm():
    """Where only two markers of a body remain, gaps up to max_gap_s are interpolated in time
    within 1 mm of truth (cubic and linear); longer gaps stay NaN, unflagged, counted missing."""
    df, _, _ = synthetic_markers(duration_s=3.0, noise_m=0.0001, seed=4)
    truth, _, _ = synthetic_markers(duration_s=3.0, noise_m=0.0, seed=4)
    short = slice(200, 229)  # 30 samples = 0.1 s
    long = slice(500, 559)  # 60 samples = 0.2 s
    for name in ("board:B1", "board:B2"):
        cols = [f"{name}_{a}_m" for a in "xyz"]
        df.loc[short.start : short.stop, cols] = np.nan
        df.loc[long.start : long.stop, cols] = np.nan
    for method in ("cubic", "linear"):
        filled, summary = fill_marker_gaps(df, body_specs(), max_gap_s=0.1, method=method)
        for name in ("board:B1", "board:B2"):
            cols = [f"{name}_{a}_m" for a in "xyz"]
            err = np.linalg.norm(filled.loc[200:229, cols].to_numpy() - truth.loc[200:229, cols].to_numpy(), axis=1)
            assert err.max() < 0.001, (method, err.max())
            assert np.isnan(filled.loc[500:559, cols].to_numpy()).all()
            assert not filled.loc[500:559, f"{name}_filled"].any()
            assert filled.loc[200:229, f"{name}_filled"].all()
            assert summary["per_marker"][name] == {"measured": 810, "rigid": 0, "interp": 30, "missing": 60}
        assert summary["total"]["interp"] == 60 and summary["total"]["missing"] == 120
    bodies = fit_bodies(filled, body_specs())
    board = bodies[bodies.body == "board"]
    assert (~board["valid"]).sum() == 60
    assert board.loc[board.frame.between(200, 229), "n_filled"].eq(2).all()


def test_gap_at_take_edge_is_not_extrapolated():
    """A gap touching the start of the take is not interpolated (no data on one side)."""
    df, _, _ = synthetic_markers(duration_s=1.0)
    cols = [f"board:B1_{a}_m" for a in "xyz"] + [f"board:B2_{a}_m" for a in "xyz"]
    df.loc[0:4, cols] = np.nan
    filled, summary = fill_marker_gaps(df, body_specs(), max_gap_s=0.1)
    assert np.isnan(filled.loc[0:4, cols].to_numpy()).all()
    assert summary["per_marker"]["board:B1"]["missing"] == 5


def test_lowpass_zero_lag_reduces_noise_and_keeps_gaps():
    """The Butterworth filtfilt reduces 1 mm white noise at least 3-fold on a 1 Hz motion with no
    phase lag (error to truth below 0.33 mm RMS away from edges), and NaN samples stay NaN."""
    rng = np.random.default_rng(5)
    t = np.arange(1500) / RATE_HZ
    truth = 0.1 * np.sin(2 * np.pi * 1.0 * t)
    noisy = truth + rng.normal(0, 0.001, t.size)
    noisy[700:720] = np.nan
    df = pd.DataFrame({"frame": np.arange(t.size), "t_s": t, "m_x_m": noisy, "m_y_m": truth, "m_z_m": truth})
    df.attrs["rate_hz"] = RATE_HZ
    out = lowpass_markers(df, cutoff_hz=6.0, order=2)
    ok = ~np.isnan(noisy)
    assert np.isnan(out["m_x_m"].to_numpy()[700:720]).all()
    err = out["m_x_m"].to_numpy()[ok] - truth[ok]
    idx = np.arange(t.size)[ok]
    interior = (np.abs(idx - 710) > 60) & (idx > 60) & (idx < t.size - 60)
    assert np.std(err[interior]) < 0.00033
    # noise-free: only the 0.08 % gain loss at 1 Hz (1e-4 m), so no lag above 0.2 ms
    np.testing.assert_allclose(out["m_y_m"].to_numpy()[100:-100], truth[100:-100], atol=1e-4)
    with pytest.raises(MocapError, match="cutoff"):
        lowpass_markers(df, cutoff_hz=200.0)


def test_repair_markers_follows_config():
    """repair_markers fills as fill_marker_gaps and low-passes only when filter.enabled."""
    df, _, _ = synthetic_markers(duration_s=1.0, noise_m=0.001, seed=13)
    df.loc[40:45, [f"board:B3_{a}_m" for a in "xyz"]] = np.nan
    cfg = {"max_gap_s": 0.1, "filter": {"enabled": False, "cutoff_hz": 12.0, "order": 2}}
    raw, summary = repair_markers(df, body_specs(), cfg)
    assert summary["filter"] is None and summary["total"]["rigid"] == 6
    np.testing.assert_array_equal(raw["board:B1_x_m"], df["board:B1_x_m"])
    cfg["filter"]["enabled"] = True
    smooth, summary = repair_markers(df, body_specs(), cfg)
    assert summary["filter"] == {"cutoff_hz": 12.0, "order": 2, "zero_lag": True}
    assert np.std(np.diff(smooth["board:B1_x_m"])) < 0.5 * np.std(np.diff(df["board:B1_x_m"]))


def test_marker_gaps_figure_has_units_and_data():
    """plot_marker_gaps returns a Figure with labelled axes in s, one row per marker, and the
    fill counts in the labels."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from cvsflow.plots.mocap import plot_marker_gaps

    df, _, _ = synthetic_markers(duration_s=1.0, noise_m=0.0002, seed=9)
    df.loc[50:59, [f"board:B2_{a}_m" for a in "xyz"]] = np.nan
    filled, summary = fill_marker_gaps(df, body_specs(), max_gap_s=0.1)
    fig = plot_marker_gaps(filled, summary)
    ax = fig.axes[0]
    assert ax.get_xlabel() == "Vicon time t (s)"
    labels = [t.get_text() for t in ax.get_yticklabels()]
    assert len(labels) == 8 and "board:B2  (10/0/0)" in labels
    plt.close(fig)
