"""The corners stage's cornerSubPix half window: corner error per rendered effect and window.

Renders each effect case of tests/unit/test_corners_effects.py (1.5 s of the demo's board at
640x480, the fast preset plus one effect, or the realistic preset; its ``EFFECTS``, the one
list of them) into ``--cache`` once, then runs the corners stage with
``corners_grid.SUBPIX_WINDOW_FRAC`` (the half window's share of the square; the tracker's
border margin follows it) set to each of ``--fracs`` and prints, against the renderer's truth,
frames kept, corners kept, the median and largest corner error (px), its ratio to a
quarter-square cornerSubPix started at the true corners (the test's reference) and the CPU
seconds of the stage. Usage::

    PYTHONPATH=. .venv/bin/python bench/bench_corner_window.py [--fracs 0.15,0.2,0.25]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from cvsflow.corners import extract_corners
from cvsflow.corners import grid as corners_grid
from cvsflow.io.media import iter_video_gray
from cvsflow.synth.render import render_session

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests" / "unit"))
import test_corners_effects as cases  # noqa: E402  (the effect cases, defined once there)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--fracs", default="0.15,0.2,0.25")
    ap.add_argument("--cases", default=",".join(sorted(cases.EFFECTS)))
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_corner_window")
    args = ap.parse_args()
    fracs = [float(x) for x in args.fracs.split(",")]
    default = (corners_grid.SUBPIX_WINDOW_FRAC, corners_grid.TRACK_BORDER_FRAC)
    print("case: per window share: frames kept, corners kept, median error px (ratio to the "
          "quarter-square reference), max error px, stage CPU s")
    for name in args.cases.split(","):
        cfg = cases.session_cfg(cases.EFFECTS[name])
        out = args.cache / name
        if not (out / "video.mp4").exists():
            out.mkdir(parents=True, exist_ok=True)
            render_session(cfg, out)
        board = cfg["board"]
        truth = pd.read_parquet(out / "truth_corners.parquet")
        truth_uv = {f: g.sort_values("corner") for f, g in truth.groupby("frame")}
        grays = {f: g for f, _, g in iter_video_gray(out / "video.mp4")}
        row = [f"{name:16s}"]
        for frac in fracs:
            corners_grid.SUBPIX_WINDOW_FRAC = corners_grid.TRACK_BORDER_FRAC = frac
            t0 = time.process_time()
            c = extract_corners(((f, 0.0, g) for f, g in grays.items()), board)
            cpu = time.process_time() - t0
            kept = c[c["found"]]
            _, err, ref = cases.scored_corners(kept, truth, truth_uv, grays, board)
            med = float(np.median(err))
            ratio = med / float(np.median(ref))
            row.append(f"{frac:g}: {kept['frame'].nunique()} fr, {len(kept)} c, {med:.3f} ({ratio:.2f}), "
                       f"max {err.max():.2f}, {cpu:.1f} s")
        corners_grid.SUBPIX_WINDOW_FRAC, corners_grid.TRACK_BORDER_FRAC = default
        print(" | ".join(row), flush=True)


if __name__ == "__main__":
    main()
