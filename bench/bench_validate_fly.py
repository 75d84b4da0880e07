"""Validate, then fly: the flight's truth check through the whole chain a user runs.

For each camera (a nominal focal length of the 640 x 480 simulated camera) and seed:

1. a validation session (:func:`cvsflow.optimise.se3_sim.simulate_session`: iid corner noise,
   a Vicon reference, 1-3 m, 20 s) starts from a calibration off the true lens by one draw of
   its stated std (``CALIB_STD_DEFAULT``, which se3 is told), and runs what the workflow runs:
   se3's held-out folds and full fit, then the compare stage (:func:`compare_heldout`), whose
   ``error_model_fit`` is the session's model (T);
2. a 60 s flight of the same camera at 3-20 m (:func:`render_flight`, ``reference="pnp"``)
   measures its reference with that se3 result (its real calibration error and stated std)
   and states it with that model, or with the rendered sessions' model for comparison;
3. the flight is evaluated (weighted SE(3) alignment, true clock) and its truth check is
   printed: z RMS per axis of recovered minus injected on-board error over the stated sigma,
   with the evaluation's own alignment and with the one fitted to the true poses.

~25 s CPU per camera and seed. Usage:

    PYTHONPATH=. .venv/bin/python bench/bench_validate_fly.py [--focal 520 700 910] [--seeds 1 2 3]
        [--range-m 3 20] [--c-cal-one]

``--c-cal-one`` adds the flight stated with the session's model at c_cal = 1 (a single session
identifies its calibration scale poorly); the pooled z RMS over the flights closes the output.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from cvsflow.flight import check_against_truth, evaluate_flight, session_error_model
from cvsflow.synth.flight_demo import render_flight
from cvsflow.synth.flight_reference import validate_simulated_session


def validate(seed, focal_px):
    """The validation session's se3 result, fitted model (T), true camera and NEES."""
    full, comparison, camera = validate_simulated_session(seed, focal_px)
    return full, session_error_model(comparison), camera, comparison["error_model"]["nees_mean"]


def main(focals, seeds, range_m=(3.0, 20.0), c_cal_one=False):
    print("z RMS per axis (x y z roll pitch yaw): own alignment | alignment fitted to the truth")
    pooled = {}
    for f_px in focals:
        for seed in seeds:
            t0 = time.process_time()
            full, model, camera, nees = validate(seed, f_px)
            print(f"f {f_px:.0f} seed {seed}: validation NEES {nees:.2f}, model s0 "
                  f"{model['s0_px']:.3f} px, s_reproj {model['s_reproj']:.3f}, c_cal "
                  f"{model['c_cal']:.3f}; fx err {full['K'][0][0] - camera['fx_px']:+.2f} px "
                  f"(std {full['std_errors']['fx']:.2f}), cx err "
                  f"{full['K'][0][2] - camera['cx_px']:+.2f} px")  # fmt: skip
            variants = [("session model", model), ("rendered model", None)]
            if c_cal_one:  # the session's fit with its poorly identified c_cal set to 1
                variants.insert(1, ("session, c_cal 1", {**model, "c_cal": 1.0}))
            for name, m in variants:
                d = render_flight(seed=seed, duration_s=60.0, reference="pnp", camera=camera,
                                  calibration=full, reference_model=m, range_m=range_m)  # fmt: skip
                r = evaluate_flight(d.reference, d.onboard, d.T_Q_B, d.Sigma_ref, clock=d.clock,
                                    weighted_alignment=True, flip_ref=d.flip_ref,
                                    cal_factor=d.cal_factor)  # fmt: skip
                c = check_against_truth(r, d.onboard, d.truth, d.T_L_C, d.clock)
                z = " ".join(f"{x:.2f}" for x in c["z_rms"].values())
                zt = " ".join(f"{x:.2f}" for x in c["z_rms_truth_alignment"].values())
                print(f"    {name:16s}: {z} | {zt} | n {c['n']}")
                pooled.setdefault(name, []).append(list(c["z_rms_truth_alignment"].values()))
            print(f"    {time.process_time() - t0:.0f} s CPU", flush=True)
    for name, z in pooled.items():
        rms = np.sqrt(np.mean(np.square(z), axis=0))
        print(f"pooled over {len(z)} flights, alignment fitted to the truth, {name}: "
              + " ".join(f"{v:.3f}" for v in rms))


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--seeds", nargs="+", type=int, default=[1, 2, 3])
    parser.add_argument("--focal", nargs="+", type=float, default=[520.0, 700.0, 910.0])
    parser.add_argument("--range-m", nargs=2, type=float, default=[3.0, 20.0])
    parser.add_argument("--c-cal-one", action="store_true",
                        help="also state the flight with the session's model at c_cal = 1")
    args = parser.parse_args()
    main(args.focal, args.seeds, tuple(args.range_m), args.c_cal_one)
