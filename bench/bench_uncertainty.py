"""Leave-one-session-out test of the error model (T) on rendered sessions.

Reads, for each session, results/<s>/heldout/se3.parquet and se3_folds.yaml (rule
heldout_se3), results/<s>/corners.parquet and the board from the config; fits model (T) on
all sessions but one and scores the one left out, per session and per time-block fold, with
the Cramer-Rao ratio and the lag-1 autocorrelation of the standardised errors. Prints the
tables and writes the scores to results/bench_uncertainty/loso.yaml. Render the sessions first
(bench/uncertainty_sessions.yaml says how). Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_uncertainty.py [session ...]

Default sessions: every session of bench/uncertainty_sessions.yaml plus ``demo`` when
results/demo/heldout exists. ``--shrink fit`` (or ``--shrink K``) shrinks each frame's
corner noise toward its session's median with a fitted (or the given) prior strength
(:func:`cvsflow.uncertainty.shrink_corner_noise`). ``--time-offset`` adds the se3 fits' time
offset to the calibration term (``parameter_covariance(time_offset=True)``). ``--corr
common`` adds model (T)'s correlated corner-noise term as a shift common to every corner of
a frame (``measurement_features(corr_length_px=CORNER_CORRELATION_PX)``, written to
loso_corr_inf.yaml), ``--corr L`` with corners correlated over L px (loso_corr_L.yaml).
``--ar1`` also fits an AR(1) of the standardised errors on the training sessions and scores
every session and fold with the errors whitened by it (``leave_one_session_out(
time_correlation=True)``, :func:`cvsflow.uncertainty.score_time_correlated`; the targets
met are counted for both; ``_ar1`` in the file name). ``--nll [session ...]`` prints each
session's held-out negative log-likelihood per frame, with and without model (T)'s
still-board codec term (``s_still``). ``--worst NAME`` instead prints, for session NAME scored by the
model fitted on the other sessions given, what its worst 5 % of frames (Mahalanobis
distance) look like and which term of model (T) dominates them (docs/findings.md).

Beside the targets met, the bench prints how many a model exactly right on the same held-out
frames would meet (``cvsflow.uncertainty.target_pass_rates``: errors drawn from each frame's
stated covariance, mean and nu, independent, AR(1) with the session's own lag-1
autocorrelation, or with its autocorrelation at every lag; 400 draws per session, seeded),
the yardstick for the count: folds of 60 time-correlated frames miss some targets whatever
the model. A fourth line gives the count of a model right up to one variance factor per
session, of the spread the held-out sessions' NEES shows beyond sampling (a model fitted on
other cameras and codecs cannot know the new one's share of pose-like corner error;
docs/findings.md).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np
import yaml

from cvsflow import uncertainty as un
from cvsflow.io.files import read_parquet, read_yaml, write_yaml
from cvsflow.io.media import video_timing
from cvsflow.metrics import ERROR_DIMS
from cvsflow.uncertainty import features as un_features
from cvsflow.uncertainty import transfer as un_transfer

ROOT = Path(__file__).resolve().parents[1]
TARGETS = un.TARGETS


def boards():
    out = {}
    for cfg in ("config/config.yaml", "bench/uncertainty_sessions.yaml"):
        for name, s in yaml.safe_load((ROOT / cfg).read_text())["sessions"].items():
            out[name] = s["board"]
    return out


def inter_coded(name):
    """corners_summary.yaml's ``inter_coded``, or (an older summary) the video's key frames."""
    summary = read_yaml(ROOT / "results" / name / "corners_summary.yaml")
    if "inter_coded" in summary:
        return bool(summary["inter_coded"])
    return video_timing(ROOT / "data" / name / "video.mp4")["inter_coded"]


def load(name, board, time_offset=False, corr_length_px=None):
    res = ROOT / "results" / name
    heldout = read_parquet(res / "heldout" / "se3.parquet")
    fits = read_yaml(res / "heldout" / "se3_folds.yaml")["folds"]
    corners = read_parquet(res / "corners.parquet")
    bodies = read_parquet(res / "bodies.parquet")
    feats = un.measurement_features(heldout, corners, board, fits=fits, bodies=bodies,
                                    time_offset=time_offset, corr_length_px=corr_length_px,
                                    inter_coded=inter_coded(name))
    # the session's pooled corner noise (what the shrinkage option pulls each frame toward)
    feats[un.NOISE_POOL_COLUMN] = un.corner_noise_pool(feats["reproj_rms_px"].to_numpy(float),
                                                       feats["n_corners"].to_numpy(float))
    sig = {int(f["fold"]): float(f["sigma_px"]) for f in fits}
    sigma_px = np.array([sig[int(k)] for k in heldout["fold"]])
    ld = [f.get("line_delay_s") for f in fits]
    return {"features": feats, "errors": heldout, "sigma_px": sigma_px, "line_delay_s": ld}


def fmt_axes(d, f="{:.3f}"):
    return " ".join(f.format(d[a]) for a in ERROR_DIMS)


def check_targets(s, met, misses, label, misses_beyond=None):
    """Count the targets of score ``s`` in ``met`` ([met, total]); list the missed ones."""
    lo, hi = TARGETS["nees"]
    met[1] += 1
    if lo <= s["nees_mean"] <= hi:
        met[0] += 1
    elif misses is not None:
        misses.append(f"{label}: NEES {s['nees_mean']:.2f}")
    for band in ("95", "68"):
        lo, hi = TARGETS[f"inside_{band}"]
        bad = {a: round(v, 3) for a, v in s[f"inside_{band}"].items() if not lo <= v <= hi}
        met[0] += len(s[f"inside_{band}"]) - len(bad)
        met[1] += len(s[f"inside_{band}"])
        if bad and misses is not None:
            misses.append(f"{label}: inside {band} {bad}")
        if misses_beyond is not None:
            tol = s[f"inside_{band}_tolerance"]
            beyond = {a: v for a, v in bad.items() if not lo - tol <= v <= hi + tol}
            if beyond:
                misses_beyond.append(f"{label}: inside {band} {beyond} "
                                     f"(+-{tol:.3f} at n_eff {s['n_effective']:.0f})")


def main(names, shrink=None, time_offset=False, corr_length_px=None, ar1=False):
    b = boards()
    if not names:
        names = [n for n in b if n != "demo" and (ROOT / "results" / n / "heldout").exists()]
        if (ROOT / "results/demo/heldout/se3.parquet").exists():
            names.append("demo")
    t0 = time.perf_counter()
    sessions = {n: load(n, b[n], time_offset, corr_length_px) for n in names}
    print(f"features of {len(names)} sessions: {time.perf_counter() - t0:.1f} s")
    for n, s in sessions.items():
        f = s["features"]
        lds = [f"{v:.3g}" if v is not None else "-" for v in s["line_delay_s"]]
        print(f"  {n}: {len(f)} held-out frames, distance {f['distance_m'].min():.2f}-"
              f"{f['distance_m'].max():.2f} m, corners {f['n_corners'].min()}-"
              f"{f['n_corners'].max()}, speed median {f['speed_px'].median():.1f} px/frame, "
              f"fold line delays {lds}")
    t0 = time.perf_counter()
    loso = un.leave_one_session_out(sessions, shrink=shrink, time_correlation=ar1)
    print(f"leave-one-session-out: {time.perf_counter() - t0:.1f} s\n")
    print("axes: " + " ".join(ERROR_DIMS))
    misses, misses_beyond = [], []
    met = {"plain": [0, 0], "ar1": [0, 0]}  # [met, total]
    met_by_session = {}
    for n, r in loso["sessions"].items():
        sc, m = r["score"], r["model"]
        print(f"{n}: n {sc['n']}, NEES {sc['nees_mean']:.2f}, model s0 {m['s0_px']:.3f} px "
              f"s_speed {m['s_speed']:.3f} s_reproj {m['s_reproj']:.2f} c_cal {m['c_cal']:.2f} "
              f"b {m['b_pos_m'] * 1e3:.2f} mm {m['b_rot_rad'] * 1e3:.2f} mrad nu {m['nu']:.1f}"
              + (f" k_shrink {m['k_shrink']:.3g}" if "k_shrink" in m else "")
              + (f" s_corr {m['s_corr']:.3f}" if "s_corr" in m else "")
              + (f" r_rs {m['r_rs']:.3f}" if "r_rs" in m else ""))
        print(f"   inside 95: {fmt_axes(sc['inside_95'])}")
        print(f"   inside 68: {fmt_axes(sc['inside_68'])}")
        print(f"   z RMS:     {fmt_axes(sc['z_rms'])}")
        print(f"   err/CRB:   {fmt_axes(sc['error_over_crb'], '{:.2f}')}")
        print(f"   lag-1 ac:  {fmt_axes(sc['lag1_autocorr'], '{:.2f}')}")
        for fs in sc["folds"]:
            print(f"   fold {fs['fold']}: n {fs['n']:3d} NEES {fs['nees_mean']:6.2f}  in95 "
                  f"{fmt_axes(fs['inside_95'])}  in68 {fmt_axes(fs['inside_68'])}")
        if "ar1" in sc:
            a = sc["ar1"]
            print(f"   AR(1) rho (fitted on the others): {fmt_axes(a['rho'], '{:.2f}')}")
            print(f"   AR(1)-whitened: NEES {a['nees_mean']:.2f}  in95 {fmt_axes(a['inside_95'])}"
                  f"  in68 {fmt_axes(a['inside_68'])}")
            print(f"   block ({a['n_blocks']} x 15 frames) z RMS: {fmt_axes(a['block_z_rms'], '{:.2f}')}")
            for fs in sc["folds"]:
                fa = fs["ar1"]
                print(f"   AR(1) fold {fs['fold']}: NEES {fa['nees_mean']:6.2f}  in95 "
                      f"{fmt_axes(fa['inside_95'])}  in68 {fmt_axes(fa['inside_68'])}")
        met_before = met["plain"][0]
        for label, s in [("session", sc)] + [(f"fold {fs['fold']}", fs) for fs in sc["folds"]]:
            check_targets(s, met["plain"], misses, f"{n} {label}", misses_beyond)
            if "ar1" in s:
                check_targets(s["ar1"], met["ar1"], None, f"{n} {label}")
        met_by_session[n] = met["plain"][0] - met_before
    yard = calibrated_yardstick(sessions, loso)
    pm = loso["pooled_model"]
    print("\npooled model (all sessions): " + ", ".join(f"{k} {pm[k]:.4g}" for k in un.TRANSFER_PARAMS))
    print(f"\ntargets met: {met['plain'][0]} of {met['plain'][1]}; per session "
          + ", ".join(f"{n} {v}" for n, v in met_by_session.items()))
    if met["ar1"][1]:
        print(f"targets met with AR(1)-whitened scores: {met['ar1'][0]} of {met['ar1'][1]}")
    for key, label in (("iid", "independent frames"),
                       ("ar1", "an AR(1) with each held-out session's own lag-1 autocorrelation"),
                       ("acf", "each held-out session's own autocorrelation at every lag"),
                       ("session", "as acf, and off by one variance factor per session, log-sd "
                                   f"{yard['session']['scale_sd']:.3f}: the sessions' NEES "
                                   "spread net of sampling"),
                       ("session_fold", "as session, and by one more per fold, log-sd "
                                        f"{yard['session_fold']['fold_scale_sd']:.3f}: the folds' "
                                        "NEES spread about their session's net of sampling")):
        y = yard[key]
        print(f"a model exactly right on these frames ({label}): {y['expected_met']:.0f} "
              f"+- {y['sd_met']:.0f} of {y['n_targets']} (5-95 %: {y['p05']:.0f}-{y['p95']:.0f}); "
              "per session " + ", ".join(f"{n} {v:.1f}" for n, v in y["per_session"].items()))
    print(f"\ntargets missed ({len(misses)}):")
    for m in misses:
        print("  " + m)
    print(f"\nband targets missed by more than a calibrated model's 2-sigma sampling scatter "
          f"(AR(1) effective n) ({len(misses_beyond)}):")
    for m in misses_beyond:
        print("  " + m)
    if "k_shrink" in pm:
        print(f"pooled model k_shrink {pm['k_shrink']:.4g}")
    if "s_corr" in pm:
        print(f"pooled model s_corr {pm['s_corr']:.4g}")
    if "r_rs" in pm:
        print(f"pooled model r_rs {pm['r_rs']:.4g}")
    tag = (("" if shrink is None else f"_shrink_{shrink}") + ("_dt" if time_offset else "")
           + ("" if corr_length_px is None else f"_corr_{corr_length_px:g}") + ("_ar1" if ar1 else ""))
    out = ROOT / "results" / "bench_uncertainty" / f"loso{tag}.yaml"
    write_yaml({"sessions": {n: r for n, r in loso["sessions"].items()},
                "pooled_model": pm, "targets_met": met["plain"][0],
                "targets_met_by_session": met_by_session,
                "targets": met["plain"][1], "targets_missed": misses,
                **({"targets_met_ar1": met["ar1"][0]} if ar1 else {}),
                "band_targets_missed_beyond_sampling": misses_beyond,
                "calibrated_yardstick": yard}, out)
    print(f"\nwritten {out.relative_to(ROOT)}")


def calibrated_yardstick(sessions, loso, n_draws=400):
    """Targets a model exactly right on the held-out frames would meet (its stated covariance,
    mean and nu for each frame; frames independent, an AR(1) with the session's own measured
    lag-1 autocorrelation, or the session's autocorrelation at every lag within a run), and
    one right only up to a variance factor per session (``session``: the autocorrelation at
    every lag, each draw's errors scaled by a log-normal factor whose log-sd is the spread of
    the held-out sessions' log NEES beyond the right model's sampling,
    :func:`cvsflow.uncertainty.session_scale_sd`): expected count, sd and 5-95 % range over
    the Monte Carlo draws, summed over sessions, and the expected count per session."""
    prepared = []  # each session's statement and time structure, once for the three kinds
    for n, r in loso["sessions"].items():
        f = sessions[n]["features"].reset_index(drop=True)
        err = sessions[n]["errors"].reset_index(drop=True)
        fold = err["fold"].to_numpy().astype(int)
        frame = err["frame"].to_numpy() if "frame" in err else np.arange(len(err))
        runs = un.frame_runs(frame, fold)
        cov = un_transfer.transfer_covariance(r["model"], f)
        mu = un_transfer.transfer_mean(r["model"], f)
        longest = int(np.max(np.unique(runs, return_counts=True)[1]))
        correlation = {
            "iid": 0.0,
            "ar1": np.clip([r["score"]["lag1_autocorr"][d] for d in ERROR_DIMS], 0.0, 0.95),
            "acf": un.autocorrelation(un.standardised_errors(cov, err, mu), runs, longest - 1),
        }
        prepared.append((n, cov, mu, r["model"]["nu"], runs, fold, correlation))
    out = {}
    nees_draws = {}
    tau, tau_fold = 0.0, 0.0
    for key in ("iid", "ar1", "acf", "session", "session_fold"):
        if key == "session":
            # right up to one factor per session, of the spread the sessions' own NEES shows
            # beyond a right model's sampling; then one per fold on top, of the spread the
            # folds' NEES shows about their session's beyond sampling
            tau = un.session_scale_sd([loso["sessions"][n]["score"]["nees_mean"] for n in nees_draws],
                                      [d[0] for d in nees_draws.values()])
            observed, sampled = [], []
            for n, d in nees_draws.items():
                sc = loso["sessions"][n]["score"]
                for j, fs in enumerate(sc["folds"], start=1):
                    observed.append(np.log(fs["nees_mean"] / sc["nees_mean"]))
                    sampled.append(np.log(d[j] / d[0]))
            tau_fold = un.excess_spread(observed, sampled)
        total, per_session, n_targets = 0, {}, 0
        for i, (n, cov, mu, nu, runs, fold, correlation) in enumerate(prepared):
            rates = un.target_pass_rates(cov, mu, nu, correlation["acf" if key.startswith("session") else key],
                                         runs, fold, n_draws=n_draws, seed=i,
                                         scale_sd=tau if key.startswith("session") else 0.0,
                                         fold_scale_sd=tau_fold if key == "session_fold" else 0.0)
            if key == "acf":
                nees_draws[n] = rates["group_nees_per_draw"]
            total = total + rates["met_per_draw"]
            n_targets += rates["n_targets"]
            per_session[n] = round(rates["expected_met"], 2)
        out[key] = {"expected_met": float(np.mean(total)), "sd_met": float(np.std(total)),
                    "p05": float(np.percentile(total, 5)), "p95": float(np.percentile(total, 95)),
                    "n_targets": n_targets, "per_session": per_session}
        if key.startswith("session"):
            out[key]["scale_sd"] = tau
        if key == "session_fold":
            out[key]["fold_scale_sd"] = tau_fold
    return out


def heldout_nll(names):
    """Each session's held-out negative log-likelihood per frame under model (T) fitted on the
    others, with and without the still board's codec term: a proper score, where the target
    count is a coarse one."""
    import pandas as pd

    b = boards()
    S = {n: load(n, b[n]) for n in names}
    total = {False: 0.0, True: 0.0}
    print("held-out NLL per frame (nats; lower is better), model (T) fitted on the other sessions")
    for held in names:
        others = [n for n in names if n != held]
        f_tr = pd.concat([S[n]["features"] for n in others], ignore_index=True)
        e_tr = pd.concat([S[n]["errors"] for n in others], ignore_index=True)
        f, e = S[held]["features"], S[held]["errors"]
        row = {}
        for still in (False, True):
            row[still] = un.transfer_nll(un.fit_transfer_model(f_tr, e_tr, still=still), f, e)
            total[still] += row[still] * len(e)
        slow = np.mean(f["speed_px"].to_numpy() < un_features.STILL_SPEED_PX)
        print(f"  {held}: without the still term {row[False]:.4f}, with {row[True]:.4f} "
              f"(gain {row[False] - row[True]:+.4f}; {slow:.0%} of frames under "
              f"{un_features.STILL_SPEED_PX} px/frame, inter-coded {bool(f['inter_coded'].iloc[0])})")
    print(f"  all: gain {total[False] - total[True]:.1f} nats over "
          f"{sum(len(S[n]['errors']) for n in names)} frames")


def worst_frames(names, held):
    """The worst held-out frames of ``held`` under the model fitted on the other ``names``."""
    import pandas as pd

    from cvsflow import flight as fl
    from cvsflow.board import board_object_points

    b = boards()
    S = {n: load(n, b[n]) for n in names}
    cols = [f"err_{d}" for d in ERROR_DIMS]
    tr = [n for n in names if n != held]
    m = un.fit_transfer_model(pd.concat([S[n]["features"] for n in tr], ignore_index=True),
                              pd.concat([S[n]["errors"] for n in tr], ignore_index=True))
    f, e = S[held]["features"], S[held]["errors"]
    Sig = un.transfer_covariance(m, f)
    E = e[cols].to_numpy() - un.transfer_mean(m, f)
    m2 = np.einsum("ni,nij,nj->n", E, np.linalg.inv(Sig), E)
    U, P, _, speed, reproj, *_ = un_transfer._transfer_terms(f)
    var_px = m["s0_px"] ** 2 + (m["s_speed"] * speed) ** 2 + (m["s_reproj"] * reproj) ** 2
    t_noise = np.einsum("nii->n", var_px[:, None, None] * U)
    t_cal = np.einsum("nii->n", m["c_cal"] ** 2 * P)
    res = ROOT / "results" / held
    fits = read_yaml(res / "heldout" / "se3_folds.yaml")["folds"]
    p_B = board_object_points(b[held])
    uv, _, _ = un.seen_corners(read_parquet(res / "corners.parquet"), e["frame"].to_numpy(),
                                len(p_B))  # fmt: skip
    rv = e[[f"cvs_rvec_{j}" for j in range(3)]].to_numpy()
    tv = e[["cvs_x_m", "cvs_y_m", "cvs_z_m"]].to_numpy()
    w = np.zeros(len(e))
    for fd in fits:
        sel = e["fold"].to_numpy() == int(fd["fold"])
        _, d_ssr = fl.pnp_flip_term(uv[sel], rv[sel], tv[sel], p_B, np.array(fd["K"]),
                                    np.array(fd["dist"]))  # fmt: skip
        w[sel] = 1.0 / (1.0 + np.exp(np.clip(d_ssr / (2.0 * var_px[sel]), -50, 50)))
    order = np.argsort(m2)[::-1]
    top = order[: max(10, len(order) // 20)]
    print(f"{held}: NEES {m2.mean():.2f}; the worst 5 % carry {m2[top].sum() / m2.sum():.0%}")
    for label, idx in (("worst 5 %", top), ("all", order)):
        ff = f.iloc[idx]
        share = np.median(t_noise[idx] / (t_noise[idx] + t_cal[idx]))
        print(f"  {label}: distance {ff.distance_m.median():.2f} m, tilt "
              f"{np.rad2deg(ff.tilt_rad.median()):.1f} deg, corners {ff.n_corners.median():.0f}, "
              f"speed {ff.speed_px.median():.1f} px/frame, reproj {ff.reproj_rms_px.median():.3f} px, "
              f"gap-filled {ff.get('vicon_filled', pd.Series([0.0])).mean():.2f}, noise share of "
              f"the trace {share:.2f}, flip weight > 0.01 on {np.mean(w[idx] > 0.01):.2f}")


if __name__ == "__main__":
    args = sys.argv[1:]
    shrink = None
    if "--shrink" in args:  # --shrink fit | K: the corner-noise shrinkage of model (T)
        i = args.index("--shrink")
        shrink = args[i + 1] if args[i + 1] == "fit" else float(args[i + 1])
        del args[i : i + 2]
    time_offset = "--time-offset" in args  # the fits' time offset in the calibration term
    if time_offset:
        args.remove("--time-offset")
    corr = None
    if "--corr" in args:  # --corr L | common: model (T)'s correlated corner noise, length L px
        i = args.index("--corr")
        corr = un.CORNER_CORRELATION_PX if args[i + 1] == "common" else float(args[i + 1])
        del args[i : i + 2]
    ar1 = "--ar1" in args  # also score the bands whitened by an AR(1) fitted on the others
    if ar1:
        args.remove("--ar1")
    if args[:1] == ["--worst"]:
        worst_frames(args[2:] or ["u_demo", "u_wide", "u_tele", "u_rs", "u_far"], args[1])
    elif args[:1] == ["--nll"]:
        heldout_nll(args[1:] or ["u_demo", "u_wide", "u_tele", "u_rs", "u_far", "demo"])
    else:
        main(args, shrink, time_offset, corr, ar1)
