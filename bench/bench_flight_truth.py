"""The flight's truth check with a physical reference, per camera (docs/findings.md).

Renders 60 s flights whose camera reference is the CVS's PnP of noisy corners
(``render_flight(reference="pnp")``), evaluates them with the true clock and a fitted SE(3)
alignment and prints the truth check's z RMS per axis (x y z roll pitch yaw), per camera and
seed, with the calibration's principal point drawn or exact; then tries the estimated clock.
~13 s CPU per flight. Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_flight_truth.py [seed ...]
"""

from __future__ import annotations

import sys
import time

from cvsflow import flight as F
from cvsflow.errors import SyncError
from cvsflow.flight_synth import CALIB_STD_DEFAULT, render_flight

CAMERAS = {
    "demo": None,
    "tele": {"fx_px": 910.0, "fy_px": 905.0, "cx_px": 329.0, "cy_px": 251.0,
             "dist": [-0.05, 0.02, 0.0, 0.0, 0.0], "width_px": 640, "height_px": 480},
    "wide": {"fx_px": 520.0, "fy_px": 518.0, "cx_px": 318.0, "cy_px": 236.0,
             "dist": [-0.28, 0.11, 0.0004, 0.0011, -0.02], "width_px": 640, "height_px": 480},
}  # fmt: skip
NO_PP = {k: v for k, v in CALIB_STD_DEFAULT.items() if k not in ("cx", "cy")}


def main(seeds):
    print("z RMS per axis: x y z roll pitch yaw")
    for name, camera in CAMERAS.items():
        for pp, calib_std in (("principal point exact", NO_PP), ("principal point drawn", None)):
            for seed in seeds:
                t0 = time.process_time()
                d = render_flight(seed=seed, duration_s=60.0, reference="pnp", camera=camera,
                                  calib_std=calib_std)  # fmt: skip
                r = F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock)
                c = F.check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
                try:
                    F.evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref)
                    sync = "estimated clock ok"
                except SyncError as exc:
                    sync = f"estimated clock: {str(exc)[:60]}"
                z = " ".join(f"{v:.2f}" for v in c["z_rms"].values())
                zt = " ".join(f"{v:.2f}" for v in c["z_rms_truth_alignment"].values())
                print(f"{name:5s} {pp:22s} seed {seed}: n {c['n']} z {z} | truth-fitted "
                      f"alignment {zt} | {sync} | {time.process_time() - t0:.0f} s CPU",
                      flush=True)  # fmt: skip


if __name__ == "__main__":
    main([int(s) for s in sys.argv[1:]] or [1, 2, 3])
