"""Vicon exports: Nexus/Tracker 'Trajectories' CSV (read and write) and C3D (read).

The in-memory form of a marker recording is a wide DataFrame at the native rate:
columns ``frame`` (int, 0-based), ``t_s`` (float, frame / rate), then for every marker
``{name}_x_m``, ``{name}_y_m``, ``{name}_z_m`` in metres in the Vicon world frame W, with NaN
where the marker was not seen. ``df.attrs["rate_hz"]`` carries the rate and
``df.attrs["markers"]`` the marker names in file order.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from cvsflow.io.files import atomic_output

AXES = ("x", "y", "z")


def marker_columns(name: str) -> list[str]:
    """The three column names of one marker in a marker table."""
    return [f"{name}_{a}_m" for a in AXES]


def marker_names(df: pd.DataFrame) -> list[str]:
    """Marker names of a wide marker table, in column order."""
    if "markers" in df.attrs:
        return list(df.attrs["markers"])
    return [c[: -len("_x_m")] for c in df.columns if c.endswith("_x_m")]


def write_nexus_csv(df: pd.DataFrame, path, rate_hz: float, decimals: int = 4) -> None:
    """Write a marker table as a Vicon Nexus 'Trajectories' CSV (mm, CRLF, empty cells for gaps).

    Frames are written 1-based as Nexus does; ``Sub Frame`` is always 0.
    """
    names = marker_names(df)
    n_cols = 2 + 3 * len(names)

    def pad(cells):
        return ",".join(cells + [""] * (n_cols - len(cells)))

    lines = [
        pad(["Trajectories"]),
        pad([f"{rate_hz:g}"]),
        ",".join(["", ""] + [c for n in names for c in (n, "", "")]),
        ",".join(["Frame", "Sub Frame"] + ["X", "Y", "Z"] * len(names)),
        ",".join(["", ""] + ["mm"] * (3 * len(names))),
    ]
    xyz_mm = df[[c for n in names for c in marker_columns(n)]].to_numpy(float) * 1000.0
    frames = df["frame"].to_numpy(int) + 1
    fmt = f"{{:.{decimals}f}}"
    for frame, row in zip(frames, xyz_mm, strict=True):
        cells = [str(frame), "0"] + ["" if np.isnan(v) else fmt.format(v) for v in row]
        lines.append(",".join(cells))
    with atomic_output(path) as tmp, open(tmp, "w", newline="") as fh:
        fh.write("\r\n".join(lines) + "\r\n")
