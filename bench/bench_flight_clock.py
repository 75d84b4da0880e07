"""The flight clock's stated uncertainty against its error, over many rendered flights.

bench_flight_truth.py prints the estimated clock of a few flights; with two or three seeds a
run of same-signed errors looks like a bias. This renders ``--seeds`` 60 s flights per
variant (seeds ``--first-seed`` on, default 1), estimates the clock as the flight stage does
(``estimate_clock`` weighted by the reference's stated rotation sigma), and prints per flight
the error at the reference's centre (ms) and in units of its stated std, the skew's error in
units of its std, then per variant the mean (with its standard error) and the RMS of both z
over the flights (a bias shows in the mean, a wrong std in the RMS: 1 if stated right) and
the RMS of the errors themselves (centre, ms; skew, ppm).

Seeds 1-12, after the robust fine step (soft_l1 in units of sigma, the log's error floor,
CR3 block sandwich); before it in brackets:

    variant        centre z: mean (se)   RMS | skew z: mean (se)   RMS | error RMS: ms    ppm
    pnp                 -0.24 (0.43)  1.46 (1.52) | +0.20 (0.40)  1.35 (2.19) | 0.979 (0.769) 40.0 (46.6)
    model               -0.05 (0.21)  0.69 (1.05) | -0.04 (0.22)  0.74 (1.09) | 0.193 (0.325) 10.2 (17.8)
    pnp_unweighted      +0.51 (0.48)  1.68 (1.75) | +0.57 (0.44)  1.56 (1.30) | 1.541 (3.993) 60.6 (105.9)

Variants (``--variants``, comma-separated): ``pnp`` (the CVS's PnP of noisy corners, principal
point exact), ``pnp_exactcal`` (and the calibration exact), ``pnp_unweighted`` (the clock fit
unweighted), ``model`` (the reference's error drawn from its stated covariance: Gaussian, no
flips), ``model_noatt`` (and no on-board attitude error). About 4 s CPU per flight for
``model``, 13 s for ``pnp``. Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_flight_clock.py [--seeds 12] [--first-seed 1]
        [--variants pnp,model]
"""

from __future__ import annotations

import argparse

import numpy as np

from cvsflow.flight import estimate_clock
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.flight_reference import CALIB_STD_DEFAULT

NO_PP = {k: v for k, v in CALIB_STD_DEFAULT.items() if k not in ("cx", "cy")}
VARIANTS = {
    "pnp": {"reference": "pnp", "calib_std": NO_PP},
    "pnp_exactcal": {"reference": "pnp", "calib_std": dict.fromkeys(CALIB_STD_DEFAULT, 0.0)},
    "pnp_unweighted": {"reference": "pnp", "calib_std": NO_PP},
    "model": {"reference": "model"},
    "model_noatt": {"reference": "model", "att_rw_rad_sqrt_s": 0.0, "att_noise_rad": 0.0},
}


def run(variant: str, seeds) -> dict[str, np.ndarray]:
    z_c, z_skew, e_cs, e_skew = [], [], [], []
    for seed in seeds:
        d = render_flight(seed=seed, duration_s=60.0, **VARIANTS[variant])
        S = d.Sigma_ref
        sigma_rot = np.sqrt((S[:, 3, 3] + S[:, 4, 4] + S[:, 5, 5]) / 3)
        k = estimate_clock(d.reference, d.onboard, R_Q_B=d.T_Q_B[:3, :3],
                           sigma_rot_rad=None if variant == "pnp_unweighted" else sigma_rot)
        D = k.details
        t_c = D["t_centre_s"]
        e_c = k.to_log(t_c) - d.clock.to_log(t_c)
        e_cs.append(e_c)
        e_skew.append(k.skew - d.clock.skew)
        z_c.append(e_c / D["dt_centre_std_s"])
        z_skew.append(e_skew[-1] / D["skew_std"])
        print(f"{variant:14s} seed {seed:2d}: centre {e_c * 1e3:+.3f} ms / "
              f"{D['dt_centre_std_s'] * 1e3:.3f} ms = {z_c[-1]:+.2f}; skew {z_skew[-1]:+.2f} sd",
              flush=True)
    return {"z_c": np.array(z_c), "z_skew": np.array(z_skew), "e_c_s": np.array(e_cs),
            "e_skew": np.array(e_skew)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="flights per variant")
    parser.add_argument("--first-seed", type=int, default=1, help="seeds first..first+N-1")
    parser.add_argument("--variants", default="pnp,model")
    args = parser.parse_args()
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    rows = [(variant, run(variant, seeds)) for variant in args.variants.split(",")]
    print("\nvariant         centre z: mean (se)   RMS | skew z: mean (se)   RMS | error RMS: "
          "centre ms  skew ppm   (z RMS 1 = std right)")
    for variant, o in rows:
        z_c, z_s = o["z_c"], o["z_skew"]
        se_c, se_s = (z.std(ddof=1) / np.sqrt(len(z)) for z in (z_c, z_s))
        print(f"{variant:14s} {z_c.mean():+12.2f} ({se_c:.2f}) {np.sqrt(np.mean(z_c**2)):5.2f} |"
              f" {z_s.mean():+10.2f} ({se_s:.2f}) {np.sqrt(np.mean(z_s**2)):5.2f} |"
              f" {np.sqrt(np.mean(o['e_c_s'] ** 2)) * 1e3:15.3f}"
              f" {np.sqrt(np.mean(o['e_skew'] ** 2)) * 1e6:9.2f}")


if __name__ == "__main__":
    main()
