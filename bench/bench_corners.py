"""Speed, memory and accuracy of the corners stage on realistic renders, per resolution.

Usage: .venv/bin/python bench/bench_corners.py [--cache DIR] [--duration-s 6]
       [--sessions webcam640,hd720,fhd1080,portrait1080] [--long-repeats 10] [--no-long]
       [--repeats 3]

Renders a short clip of each session of config/config.yaml + config/realistic.yaml
(``synth.preset: realistic``: 640x480, 1280x720, 1920x1080 HEVC, portrait 1080x1920) with the
package's renderer into DIR (default /tmp/cvsflow_bench_corners; reused while the clip's
length matches), then runs, each in a fresh process pinned to one CPU (one OpenCV thread,
OMP/OPENBLAS threads 1), reading the video as the workflow does:

- ``decode``: reading the video to grey frames only (``iter_video_gray``), the ceiling;
- ``stage``: the corners stage (``extract_corners`` on ``iter_video_gray``, decoding included);
- ``plain``: plain OpenCV on every frame (``findChessboardCorners`` with adaptive threshold,
  normalise and fast check, then ``cornerSubPix`` with the window scaled to the squares), the
  reference for recall and corner error (its result is cached in DIR).

The table gives frames/s of decode and stage side by side (their ratio is the target: >= 0.5,
measured in the same run so that the machine's load cancels), peak resident memory, and
against the renderer's truth: recall over frames with the board wholly visible and not
occluded, recall over the frames plain OpenCV finds, frames found with some corners hidden
(partial), flipped frames (a kept corner more than half a square from its true corner) and
the corner error (px) median / p95 of the stage and of the plain reference on the frames both
found. With a long clip (``--long-repeats``: the 1080p clip's frames encoded that many times
over with PyAV) the stage's peak memory on the long and the short clip shows whether it holds
frames. Timings are noisy on a shared machine; compare ratios within one run.
"""

from __future__ import annotations

import argparse
import contextlib
import copy
import fractions
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
SESSIONS = ("webcam640", "hd720", "fhd1080", "portrait1080")
# The plain reference: what a user's own OpenCV loop would find.
PLAIN_SUBPIX_FRAC = 0.15


CONFIG = REPO / "config" / "realistic.yaml"


def _session_cfg(name: str, config: Path = CONFIG) -> dict:
    import yaml

    with open(config) as fh:
        return copy.deepcopy(yaml.safe_load(fh)["sessions"][name])


def _render(cache: Path, name: str, duration_s: float, config: Path = CONFIG) -> Path:
    """Render session ``name`` for ``duration_s`` into cache/name unless it is there."""
    import yaml

    from cvsflow.synth.render import render_session

    out = cache / name
    stamp = out / "bench_duration.json"
    if stamp.is_file() and json.loads(stamp.read_text()) == duration_s:
        return out
    cfg = _session_cfg(name, config)
    cfg["synth"]["duration_s"] = duration_s
    start = time.perf_counter()
    with _lenient_stills():
        render_session(cfg, out)
    stamp.write_text(json.dumps(duration_s))
    for old in out.glob("bench_*.parquet"):
        old.unlink()
    print(f"rendered {name} ({yaml.safe_dump(cfg['synth']['image_size']).strip()}) in "
          f"{time.perf_counter() - start:.0f} s", file=sys.stderr)
    return out


@contextlib.contextmanager
def _lenient_stills():
    """Let a session render whose calibration stills cannot all be placed (webcam640's wide
    lens: 11 of 15 in view), by repeating the last one found. The stills come from their own
    random stream, so the video is the one the session's config gives; the bench uses no
    stills."""
    import cvsflow.synth.render as synth

    original = synth.still_poses

    def lenient(rng, n, *args, **kwargs):
        got = original(rng, n, *args, **kwargs)
        if 0 < len(got) < n:
            got = np.concatenate([got, np.repeat(got[-1:], n - len(got), axis=0)])
        return got

    synth.still_poses = lenient
    try:
        yield
    finally:
        synth.still_poses = original


def _long_video(short: Path, out: Path, repeats: int) -> Path:
    """The short clip's frames encoded ``repeats`` times over (H.264, 30 fps), streaming."""
    import av

    if out.is_file() and out.stat().st_mtime > short.stat().st_mtime:
        return out
    tmp = out.with_suffix(".part.mp4")
    with av.open(str(tmp), "w") as dst:
        stream = None
        i = 0
        for _ in range(repeats):
            with av.open(str(short)) as src:
                for frame in src.decode(video=0):
                    if stream is None:
                        stream = dst.add_stream("libx264", rate=30)
                        stream.width, stream.height = frame.width, frame.height
                        stream.pix_fmt = "yuv420p"
                        stream.options = {"crf": "23", "preset": "veryfast"}
                    frame = frame.reformat(format="yuv420p")
                    frame.pts = i
                    frame.time_base = fractions.Fraction(1, 30)
                    i += 1
                    for packet in stream.encode(frame):
                        dst.mux(packet)
        for packet in stream.encode():
            dst.mux(packet)
    tmp.rename(out)
    return out


def _one_core() -> None:
    """This process on one CPU, one OpenCV thread."""
    import cv2

    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
    cv2.setNumThreads(1)


def _plain(video: Path, board: dict):
    """Plain OpenCV on every frame: (frame, corner, u_px, v_px) rows of the found frames."""
    import cv2
    import numpy as np
    import pandas as pd

    from cvsflow.board import SUBPIX_CRITERIA, board_pattern
    from cvsflow.io.media import iter_video_gray

    pattern = board_pattern(board)
    flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_FAST_CHECK
    rows = []
    for frame, _, gray in iter_video_gray(video):
        found, c = cv2.findChessboardCorners(gray, pattern, None, flags)
        if not found:
            continue
        grid = c.reshape(pattern[1], pattern[0], 2)
        d = np.concatenate([np.linalg.norm(np.diff(grid, axis=a), axis=-1).ravel()
                            for a in (0, 1)])
        w = int(max(2, min(max(5, round(PLAIN_SUBPIX_FRAC * np.median(d))),
                           (d.min() - 1.0) // 2)))
        try:
            c = cv2.cornerSubPix(gray, c, (w, w), (-1, -1), SUBPIX_CRITERIA)
        except cv2.error:
            continue
        uv = c.reshape(-1, 2)
        rows.append(pd.DataFrame({"frame": frame, "corner": np.arange(len(uv)),
                                  "u_px": uv[:, 0], "v_px": uv[:, 1]}))
    cols = {"frame": [], "corner": [], "u_px": [], "v_px": []}
    return pd.concat(rows, ignore_index=True) if rows else pd.DataFrame(cols)


def _run_variant(name: str, video: Path, out: Path, board: dict) -> dict:
    """One variant in this process (one core); writes its table to ``out``; returns timings."""
    _one_core()
    from cvsflow.corners import extract_corners
    from cvsflow.io.media import iter_video_gray

    wall0, cpu0 = time.perf_counter(), time.process_time()
    table = None
    if name == "decode":
        n = sum(1 for _ in iter_video_gray(video))
    elif name == "stage":
        table = extract_corners(iter_video_gray(video), board, log_every=0)
        n = int(table["frame"].nunique())
    else:
        table = _plain(video, board)
        n = None
    wall = time.perf_counter() - wall0
    cpu = time.process_time() - cpu0
    if table is not None:
        table.to_parquet(out)
    peak_mb = _peak_rss_mb()
    return {"frames": n, "wall_s": wall, "cpu_s": cpu, "peak_mb": peak_mb,
            "methods": table.attrs.get("order_methods") if name == "stage" else None}


def _peak_rss_mb() -> float:
    """Peak resident memory of this process, MB: VmHWM (ru_maxrss survives exec on Linux, so
    a child would report its parent's peak)."""
    try:
        with open("/proc/self/status") as fh:
            for line in fh:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def _spawn(variant: str, video: Path, out: Path, session: str, config: Path = CONFIG) -> dict:
    env = dict(os.environ, OMP_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, __file__, "--variant", variant, "--video", str(video), "--out",
         str(out), "--sessions", session, "--config", str(config)],
        check=True, capture_output=True, text=True, env=env,
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _accuracy(stage, plain, truth_frames, truth_corners, nx) -> dict:
    """Recall, partial frames, flips and corner errors of the stage against the truth."""
    import numpy as np

    n_corners = int(truth_corners["corner"].max()) + 1
    tf = truth_frames.set_index("frame")
    whole = tf["in_view"].astype(bool)
    if "n_occluded" in tf:
        whole &= (tf["n_occluded"] == 0) & (tf["n_visible"] == n_corners)
    found = stage.groupby("frame")["found"].first().reindex(tf.index, fill_value=False)
    per_frame = stage[stage["found"]].groupby("frame").size()
    plain_found = found.index.isin(plain["frame"].unique())
    tc = truth_corners.set_index(["frame", "corner"])[["u_px", "v_px"]]
    # Square size at each corner: distance to the next corner along the row in the truth.
    tu = truth_corners.sort_values(["frame", "corner"])
    grid = tu[["u_px", "v_px"]].to_numpy().reshape(len(tf), -1, nx, 2)
    step = np.linalg.norm(np.diff(grid, axis=2), axis=-1)
    spacing = np.concatenate([step, step[:, :, -1:]], axis=2).reshape(len(tf), -1)

    def errors(table):
        t = table[table["found"]] if "found" in table else table
        t = t[t["corner"] >= 0]
        true = tc.reindex(list(zip(t["frame"], t["corner"], strict=True))).to_numpy()
        err = np.hypot(t["u_px"].to_numpy() - true[:, 0], t["v_px"].to_numpy() - true[:, 1])
        sq = spacing[t["frame"].to_numpy(), t["corner"].to_numpy()]
        return t["frame"].to_numpy(), err, sq

    f_s, e_s, sq_s = errors(stage)
    flipped = np.unique(f_s[e_s > 0.5 * sq_s])
    f_p, e_p, sq_p = errors(plain)
    # Plain OpenCV's order is its own (it may start at either end): its error is taken in
    # whichever of the two orders is nearer the truth, frame by frame.
    if len(plain):
        rev = plain.assign(corner=n_corners - 1 - plain["corner"])
        _, e_r, _ = errors(rev)
        import pandas as pd

        a = pd.Series(e_p).groupby(f_p).median()
        b = pd.Series(e_r).groupby(f_p).median()
        use_rev = (b < a).reindex(f_p).to_numpy()
        e_p = np.where(use_rev, e_r, e_p)
    both = np.intersect1d(np.unique(f_s), np.unique(f_p))
    es, ep = e_s[np.isin(f_s, both)], e_p[np.isin(f_p, both)]

    def q(e):
        return (float(np.median(e)), float(np.percentile(e, 95))) if len(e) else (np.nan, np.nan)

    return {
        "n_frames": len(tf),
        "whole": int(whole.sum()),
        "found_whole": int(found[whole].sum()),
        "plain": int(plain_found.sum()),
        "found_plain": int(found[plain_found].sum()),
        "partial": int((per_frame < n_corners).sum()),
        "found": int(found.sum()),
        "flipped": len(flipped),
        "err_stage": q(es),
        "err_plain": q(ep),
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--cache", type=Path, default=Path(tempfile.gettempdir()) / "cvsflow_bench_corners"
    )
    parser.add_argument("--duration-s", type=float, default=6.0)
    parser.add_argument("--sessions", default=",".join(SESSIONS))
    parser.add_argument("--config", type=Path, default=CONFIG,
                        help="YAML whose sessions: to render (default config/realistic.yaml; "
                             "e.g. bench/robustness_sessions.yaml)")
    parser.add_argument("--long-repeats", type=int, default=10)
    parser.add_argument("--no-long", action="store_true")
    parser.add_argument("--repeats", type=int, default=1,
                        help="decode and stage runs per session (alternating); the least CPU "
                             "time of each is reported")
    parser.add_argument("--variant", help=argparse.SUPPRESS)  # internal: run one, print JSON
    parser.add_argument("--video", type=Path, help=argparse.SUPPRESS)
    parser.add_argument("--out", type=Path, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.variant:
        board = _session_cfg(args.sessions, args.config)["board"]
        print(json.dumps(_run_variant(args.variant, args.video, args.out, board)))
        return

    import pandas as pd

    from cvsflow.board import board_pattern

    cache = args.cache.resolve()
    cache.mkdir(parents=True, exist_ok=True)
    import cvsflow

    print(f"cvsflow from {Path(cvsflow.__file__).parent}; clips of {args.duration_s:g} s; "
          "one core per process")
    header = (f"{'session':13s} {'size':>9s} {'frames':>6s} {'decode/s':>8s} {'stage/s':>7s} "
              f"{'ratio':>5s} {'MB dec':>6s} {'MB stg':>6s} {'whole':>9s} {'plain':>9s} "
              f"{'partial':>7s} {'flips':>5s}  err px stage med/p95 | plain med/p95")
    print(header, flush=True)
    details = []
    for name in args.sessions.split(","):
        folder = _render(cache, name, args.duration_s, args.config)
        video = folder / "video.mp4"
        cfg = _session_cfg(name, args.config)
        nx, _ = board_pattern(cfg["board"])
        plain_path = folder / "bench_plain.parquet"
        if not plain_path.is_file():
            _spawn("plain", video, plain_path, name, args.config)
        # Alternating runs, the least CPU time of each: the machine's load only adds time.
        dec = stg = None
        for _ in range(max(1, args.repeats)):
            d = _spawn("decode", video, folder / "bench_decode.parquet", name, args.config)
            s = _spawn("stage", video, folder / "bench_stage.parquet", name, args.config)
            dec = d if dec is None or d["cpu_s"] < dec["cpu_s"] else dec
            stg = s if stg is None or s["cpu_s"] < stg["cpu_s"] else stg
        acc = _accuracy(pd.read_parquet(folder / "bench_stage.parquet"),
                        pd.read_parquet(plain_path),
                        pd.read_parquet(folder / "truth_frames.parquet"),
                        pd.read_parquet(folder / "truth_corners.parquet"), nx)
        w, h = cfg["synth"]["image_size"]
        fd, fs = dec["frames"] / dec["cpu_s"], stg["frames"] / stg["cpu_s"]
        print(
            f"{name:13s} {f'{w}x{h}':>9s} {acc['n_frames']:6d} {fd:8.0f} {fs:7.0f} "
            f"{fs / fd:5.2f} {dec['peak_mb']:6.0f} {stg['peak_mb']:6.0f} "
            f"{acc['found_whole']:4d}/{acc['whole']:<4d} {acc['found_plain']:4d}/{acc['plain']:<4d} "
            f"{acc['partial']:7d} {acc['flipped']:5d}  "
            "{:.3f}/{:.3f} | {:.3f}/{:.3f}".format(*acc["err_stage"], *acc["err_plain"]),
            flush=True,
        )
        details.append(f"{name}: frames by method {stg['methods']}")
    if not args.no_long and "fhd1080" in args.sessions.split(","):
        short = cache / "fhd1080" / "video.mp4"
        long_video = _long_video(short, cache / f"fhd1080_long_x{args.long_repeats}.mp4",
                                 args.long_repeats)
        for label, video in (("short", short), ("long", long_video)):
            dec = _spawn("decode", video, cache / "bench_long_decode.parquet", "fhd1080")
            stg = _spawn("stage", video, cache / "bench_long_stage.parquet", "fhd1080")
            fd, fs = dec["frames"] / dec["cpu_s"], stg["frames"] / stg["cpu_s"]
            details.append(
                f"memory fhd1080 {label:5s}: {stg['frames']:5d} frames, decode {fd:.0f}/s "
                f"peak {dec['peak_mb']:.0f} MB, stage {fs:.0f}/s peak {stg['peak_mb']:.0f} MB"
            )
    print("\n".join(details))
    print(f"frames/s by CPU time of the process (one core; the least of {max(1, args.repeats)} "
          "runs); ratio = stage / decode (target >= 0.5); whole = found / frames wholly "
          "visible and not occluded; plain = found / frames plain OpenCV finds; err on the "
          "frames both found")


if __name__ == "__main__":
    main()
