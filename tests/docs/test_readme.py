"""The README: short, its two set-up commands real, its quick-start numbers those of the demo's files.

The demo's files are the golden tables in tests/golden/demo/ (what `make demo` writes;
tests/workflow/test_golden.py holds a fresh demo run to them within stated tolerances), so a
change that moves a quick-start number fails here until the README quotes the new one.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import yaml

REPO = Path(__file__).resolve().parents[2]
GOLDEN = REPO / "tests" / "golden" / "demo"
README = REPO / "README.md"


def _y(path):
    return yaml.safe_load((GOLDEN / path).read_text())


def quickstart_numbers() -> dict[str, str]:
    """Each quick-start row's numbers as the README prints them, from the demo's files."""
    cam, sync = _y("demo/camera.yaml"), _y("demo/sync.yaml")
    se3, cmp = _y("demo/se3/calib/result.yaml"), _y("demo/comparison.yaml")
    seed, flight = _y("demo/seed/calib/result.yaml"), _y("flights/flight_demo/stats.yaml")
    K, std = cam["K"], se3["std_errors"]
    rms = {d: v["rmse"] for d, v in cmp["se3"]["per_dim"].items()}
    em = cmp["error_model"]
    return {
        "calibration": f"fx {K[0][0]:.2f}, fy {K[1][1]:.2f}, cx {K[0][2]:.2f}, cy {K[1][2]:.2f} px, "
                       f"RMS {cam['rms_px']:.3f} px",
        "sync offset": f"{sync['dt_offset_s']:.4f} s, quality {sync['quality']:.2f}",
        "se3": f"fx {se3['fx_px']:.2f} ± {std['fx']:.2f}, fy {se3['fy_px']:.2f} ± {std['fy']:.2f} px; "
               f"dt {se3['dt_offset_s']:.5f} s ± {1e3 * std['dt_offset_s']:.3f} ms; "
               f"reprojection RMS {se3['rms_px']:.3f} px",
        "held-out RMS": f"x {1e3 * rms['x_m']:.2f}, y {1e3 * rms['y_m']:.2f}, z {1e3 * rms['z_m']:.2f} mm; "
                        f"roll {math.degrees(rms['roll_rad']):.2f}, pitch {math.degrees(rms['pitch_rad']):.2f}, "
                        f"yaw {math.degrees(rms['yaw_rad']):.2f} deg",
        "stated uncertainty": f"{100 * em['inside_68_all']:.1f} % inside the 68 % band, "
                              f"{100 * em['inside_95_all']:.1f} % inside the 95 % band, "
                              f"mean NEES {em['nees_mean']:.2f}",
        "seed": "diverged" if seed.get("diverged") else "converged",
        "flight": f"APE translation RMSE {1e3 * flight['ape_trans']['rmse']:.1f} mm, "
                  f"rotation RMSE {math.degrees(flight['ape_rot']['rmse']):.2f} deg",
    }


def test_readme_quick_start_numbers_are_the_demo_files():
    """Every number of the README's demo table, and of the guide's copy, is what the demo's files
    hold, as printed."""
    text = README.read_text()
    table = text.split("## The demo", 1)[1].split("\n## ", 1)[0]
    guide = (REPO / "docs" / "getting-started.md").read_text()
    for row, numbers in quickstart_numbers().items():
        assert numbers in table, f"README's demo row {row!r} should read {numbers!r}"
        assert numbers in guide, f"docs/getting-started.md's demo row {row!r} should read {numbers!r}"


def test_readme_is_short_and_its_set_up_commands_are_real():
    """At most 250 lines; `make demo` and `make test` are Makefile targets and CI runs the test one."""
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    make = (REPO / "Makefile").read_text()
    for target in ("demo", "test"):
        assert f"\nmake {target} " in text
        assert re.search(rf"^{target}: install$", make, re.M), target
    assert re.search(r"^make test$", (REPO / ".ci" / "run").read_text(), re.M)


def test_readme_links_point_at_files_in_the_repository():
    """Every relative link of the README names a file of the repository (the guide's pages)."""
    text = README.read_text()
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if "://" in target:
            continue
        assert (REPO / target).exists(), target
