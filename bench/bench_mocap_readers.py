"""Speed of the motion-capture readers on the real exports (shared/data/real), against the Nexus reader.

Usage: .venv/bin/python bench/bench_mocap_readers.py [--repeat 5] [--root shared/data/real]

For each real export (Vicon Nexus CSV, Motive CSV with a rigid body, Motive 360 Hz unlabelled,
QTM 3D, QTM 6D) prints the file size, frames, the best of ``--repeat`` wall times of
``read_mocap`` (detection included), frames/s and cells/s, and the cells/s as a ratio to the
Nexus CSV reader's in the same run (the ratio is what to compare across machines: the shared
machine makes absolute times noisy).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from cvsflow.io.mocap.formats import read_mocap

FILES = [
    ("vicon/markers.csv", "Nexus CSV"),
    ("mocap/optitrack-motive/grvc_rigidbody_test/test.csv", "Motive, rigid body"),
    ("mocap/optitrack-motive/ha5dzs_unlabeled_markers_360hz/test_markers_enabled.csv", "Motive, 360 Hz"),
    ("mocap/qualisys-qtm/imusim_swing_3D/swing_3D.tsv", "QTM 3D"),
    ("mocap/qualisys-qtm/imusim_swing_6D/swing_6D.tsv", "QTM 6D"),
]


def _default_root() -> Path:
    for up in Path(__file__).resolve().parents:
        if (up / "shared" / "data" / "real").is_dir():
            return up / "shared" / "data" / "real"
    return Path("shared/data/real")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--root", type=Path, default=_default_root())
    args = ap.parse_args()
    rows = []
    for rel, label in FILES:
        path = args.root / rel
        if not path.exists():
            print(f"{label:20s} missing: {path}")
            continue
        best = float("inf")
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            e = read_mocap(path)
            best = min(best, time.perf_counter() - t0)
        n = len(e.markers)
        cells = e.markers.shape[1] - 2 + (0 if e.bodies is None else 7 * len(e.body_names))
        rows.append((label, path.stat().st_size, n, best, n * cells / best))
    ref = rows[0][4] if rows and rows[0][0] == "Nexus CSV" else None
    print(f"{'export':20s} {'bytes':>9s} {'frames':>7s} {'best s':>8s} {'frames/s':>10s} {'cells/s':>10s} {'vs Nexus':>8s}")
    for label, size, n, best, cps in rows:
        ratio = f"{cps / ref:8.2f}" if ref else "       -"
        print(f"{label:20s} {size:9d} {n:7d} {best:8.4f} {n / best:10.0f} {cps:10.3g} {ratio}")


if __name__ == "__main__":
    main()
