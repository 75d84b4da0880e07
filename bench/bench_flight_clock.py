"""The flight clock's stated uncertainty against its error, over many rendered flights.

bench_flight_truth.py prints the estimated clock of a few flights; with two or three seeds a
run of same-signed errors looks like a bias. This renders ``--seeds`` 60 s flights per
variant, estimates the clock as the flight stage does (``estimate_clock`` weighted by the
reference's stated rotation sigma), and prints per flight the error at the reference's centre
(ms) and in units of its stated std, the skew's error in units of its std, then the mean (with
its standard error) and the RMS of both z over the flights: a bias shows in the mean, a wrong
std in the RMS (1 if stated right).

Variants (``--variants``, comma-separated): ``pnp`` (the CVS's PnP of noisy corners, principal
point exact), ``pnp_exactcal`` (and the calibration exact), ``pnp_unweighted`` (the clock fit
unweighted), ``model`` (the reference's error drawn from its stated covariance: Gaussian, no
flips), ``model_noatt`` (and no on-board attitude error). About 4 s CPU per flight for
``model``, 13 s for ``pnp``. Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_flight_clock.py [--seeds 12] [--variants pnp,model]
"""

from __future__ import annotations

import argparse

import numpy as np

from cvsflow.flight.clock import estimate_clock
from cvsflow.flight_reference_synth import CALIB_STD_DEFAULT
from cvsflow.flight_synth import render_flight

NO_PP = {k: v for k, v in CALIB_STD_DEFAULT.items() if k not in ("cx", "cy")}
VARIANTS = {
    "pnp": {"reference": "pnp", "calib_std": NO_PP},
    "pnp_exactcal": {"reference": "pnp", "calib_std": dict.fromkeys(CALIB_STD_DEFAULT, 0.0)},
    "pnp_unweighted": {"reference": "pnp", "calib_std": NO_PP},
    "model": {"reference": "model"},
    "model_noatt": {"reference": "model", "att_rw_rad_sqrt_s": 0.0, "att_noise_rad": 0.0},
}


def run(variant: str, seeds) -> tuple[np.ndarray, np.ndarray]:
    z_c, z_skew = [], []
    for seed in seeds:
        d = render_flight(seed=seed, duration_s=60.0, **VARIANTS[variant])
        S = d.Sigma_ref
        sigma_rot = np.sqrt((S[:, 3, 3] + S[:, 4, 4] + S[:, 5, 5]) / 3)
        k = estimate_clock(d.reference, d.onboard, R_Q_B=d.T_Q_B[:3, :3],
                           sigma_rot_rad=None if variant == "pnp_unweighted" else sigma_rot)
        D = k.details
        t_c = D["t_centre_s"]
        e_c = k.to_log(t_c) - d.clock.to_log(t_c)
        z_c.append(e_c / D["dt_centre_std_s"])
        z_skew.append((k.skew - d.clock.skew) / D["skew_std"])
        print(f"{variant:14s} seed {seed:2d}: centre {e_c * 1e3:+.3f} ms / "
              f"{D['dt_centre_std_s'] * 1e3:.3f} ms = {z_c[-1]:+.2f}; skew {z_skew[-1]:+.2f} sd",
              flush=True)
    return np.array(z_c), np.array(z_skew)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12, help="flights per variant (seeds 1..N)")
    parser.add_argument("--variants", default="pnp,model")
    args = parser.parse_args()
    rows = []
    for variant in args.variants.split(","):
        z_c, z_s = run(variant, range(1, args.seeds + 1))
        rows.append((variant, z_c, z_s))
    print("\nvariant         centre z: mean (se)    RMS | skew z: mean    RMS   (RMS 1 = std right)")
    for variant, z_c, z_s in rows:
        se = z_c.std(ddof=1) / np.sqrt(len(z_c))
        print(f"{variant:14s} {z_c.mean():+12.2f} ({se:.2f}) {np.sqrt(np.mean(z_c**2)):6.2f} |"
              f" {z_s.mean():+8.2f} {np.sqrt(np.mean(z_s**2)):6.2f}")


if __name__ == "__main__":
    main()
