"""The flight's truth check with a physical reference, per camera (docs/findings.md).

Renders 60 s flights whose camera reference is the CVS's PnP of noisy corners
(``render_flight(reference="pnp")``), evaluates them with the true clock and a fitted SE(3)
alignment, unweighted and weighted by the reference covariance (``weighted_alignment``), and
prints the truth check's z RMS per axis (x y z roll pitch yaw) with the evaluation's own and the
truth-fitted alignment, per camera and seed, with the calibration's principal point drawn or
exact; then estimates the clock and prints its offset error against the injected clock in
units of its stated standard deviation (at the reference's centre, and of ``dt_offset_s``) and
the skew's. ~13 s CPU per flight. ``--s-reproj X`` states the reference's covariance with
model (T)'s s_reproj set to X (1 is right for these flights' iid corners; the fitted 1.127
comes from rendered images), ``--no-flips`` without the PnP ambiguity term, ``--validation``
with the model (T) the compare stage fits on a simulated validation session of the flights'
corner noise (validate, then fly: :func:`validation_model`). Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_flight_truth.py [--s-reproj X] [--no-flips] \
        [--validation] [seed ...]
"""

from __future__ import annotations

import argparse
import functools
import time

import cvsflow.synth.flight_reference as reference_synth
from cvsflow import uncertainty as un
from cvsflow.exceptions import SyncError
from cvsflow.flight import check_against_truth, estimate_clock, evaluate_flight, session_error_model
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.flight_reference import CALIB_STD_DEFAULT, validate_simulated_session

CAMERAS = {
    "demo": None,
    "tele": {"fx_px": 910.0, "fy_px": 905.0, "cx_px": 329.0, "cy_px": 251.0,
             "dist": [-0.05, 0.02, 0.0, 0.0, 0.0], "width_px": 640, "height_px": 480},
    "wide": {"fx_px": 520.0, "fy_px": 518.0, "cx_px": 318.0, "cy_px": 236.0,
             "dist": [-0.28, 0.11, 0.0004, 0.0011, -0.02], "width_px": 640, "height_px": 480},
}  # fmt: skip
NO_PP = {k: v for k, v in CALIB_STD_DEFAULT.items() if k not in ("cx", "cy")}


def validation_model():
    """Model (T) as the compare stage fits it (comparison.yaml ``error_model_fit``) on a
    simulated validation session of the demo's lens (:func:`validate_simulated_session`)."""
    return session_error_model(validate_simulated_session(5)[1])


def main(seeds, model=None):
    print("z RMS per axis: x y z roll pitch yaw")
    for name, camera in CAMERAS.items():
        for pp, calib_std in (("principal point exact", NO_PP), ("principal point drawn", None)):
            for seed in seeds:
                t0 = time.process_time()
                d = render_flight(seed=seed, duration_s=60.0, reference="pnp", camera=camera,
                                  calib_std=calib_std, reference_model=model)  # fmt: skip
                line = f"{name:5s} {pp:22s} seed {seed}:"
                for weighted in (False, True):
                    r = evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref,
                                        clock=d.clock, weighted_alignment=weighted,
                                        flip_ref=d.flip_ref, cal_factor=d.cal_factor)  # fmt: skip
                    c = check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
                    z = " ".join(f"{v:.2f}" for v in c["z_rms"].values())
                    zt = " ".join(f"{v:.2f}" for v in c["z_rms_truth_alignment"].values())
                    line += (f" | {'weighted' if weighted else 'unweighted'}: z {z}, truth-fitted"
                             f" {zt}")  # fmt: skip
                print(f"{line} | n {c['n']}", flush=True)
                sigma_rot = (d.Sigma_ref[:, 3, 3] + d.Sigma_ref[:, 4, 4] + d.Sigma_ref[:, 5, 5]) / 3
                try:
                    k = estimate_clock(d.reference, d.onboard, R_Q_B=d.T_Q_B[:3, :3],
                                       sigma_rot_rad=sigma_rot**0.5)  # fmt: skip
                except SyncError as exc:
                    print(f"      estimated clock: {str(exc)[:100]}", flush=True)
                    continue
                D = k.details
                t_c = D["t_centre_s"]
                e_c = k.to_log(t_c) - d.clock.to_log(t_c)
                e_o = k.dt_offset_s - d.clock.dt_offset_s
                print(f"      estimated clock (speed baseline {D['xcorr_baseline_s']} s, peak "
                      f"{k.quality:.2f}): centre {e_c * 1e3:+.2f} ms / {D['dt_centre_std_s'] * 1e3:.2f}"
                      f" ms = {e_c / D['dt_centre_std_s']:+.2f}; dt_offset {e_o * 1e3:+.2f} ms / "
                      f"{D['dt_offset_std_s'] * 1e3:.2f} ms = {e_o / D['dt_offset_std_s']:+.2f}; "
                      f"skew {(k.skew - d.clock.skew) / D['skew_std']:+.2f} sd | "
                      f"{time.process_time() - t0:.0f} s CPU", flush=True)  # fmt: skip


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("seeds", nargs="*", type=int, default=[1, 2, 3])
    parser.add_argument("--s-reproj", type=float, default=None)
    parser.add_argument("--no-flips", action="store_true")
    parser.add_argument("--validation", action="store_true")
    args = parser.parse_args()
    if args.s_reproj is not None:
        un.RENDERED_TRANSFER_MODEL["s_reproj"] = args.s_reproj  # read at each flight's call
    if args.no_flips:
        reference_synth.reference_covariance_transfer = functools.partial(
            reference_synth.reference_covariance_transfer, flips=False)
    model = None
    if args.validation:
        model = validation_model()
        print("model (T) of the validation session:",
              {k: round(v, 4) for k, v in model.items() if isinstance(v, float)})
    main(args.seeds, model)
