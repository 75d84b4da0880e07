"""Corner noise against the renderer's truth: codec, render path and cornerSubPix window.

Renders a short clip of a session of bench/uncertainty_sessions.yaml (or config/config.yaml)
in memory and extracts its corners (``corners_detect.detect_corners``, every frame on its own) from

- ``raw``: the rendered frames themselves (lossless, no encoder);
- ``png``: the same frames through a PNG round trip (a lossless file path: must equal raw);
- ``mpeg4``: the same frames through the realistic path's writer (PyAV ``mpeg4``, fixed
  quantiser from ``video_quality``, ``PyAvVideoSink``), decoded again;
- ``mpeg4intra``: as ``mpeg4`` with every frame a key frame (no inter-frame prediction);
- ``legacy``: the same frames through the demo path's writer (a JPEG round trip at
  ``video_quality``, then OpenCV's ``mp4v``, ``VideoSink``), decoded again;

and, with ``--raster``, the frames of the other rasteriser (``Renderer.video_frame``, the demo
path, full-image ``render_board``, versus ``Renderer.realistic_frame``, ROI
``render_board_region``) with the same poses, lighting and noise draws, raw and through both
writers. Against the true corners it prints, per variant and over frames where every corner
was found: the corner noise sigma (px, RMS of the part PnP cannot absorb, per residual degree of
freedom), and each of these modes' energy over sigma^2 (1 for independent corner noise):
the absorbed part (PnP's 6-DOF column space, per DOF), the common shift (x, y), scale and
rotation about the corners' centroid; the common shift's lag-1 autocorrelation over
consecutive frames and its mean (a bias, px). ``--windows 2,3,4,5`` repeats the detection
with those ``subpix_window_px`` values (the largest cornerSubPix half window) on the raw and
mpeg4 frames and prints the half window actually used (``corners_grid._subpix_window``).

Usage::

    PYTHONPATH=. nice -n 10 .venv/bin/python bench/bench_codec_corners.py u_far \
        [--duration-s 4] [--distance-m 1.5,4.5] [--raster] [--windows 2,3,4,5] [--cache DIR]
        [--from-s 2]

Writes the per-variant table to DIR/<session>_<tag>.yaml (default DIR /tmp/bench_codec_corners).
"""

from __future__ import annotations

import argparse
import copy
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import yaml

from cvsflow.board import SUBPIX_CRITERIA
from cvsflow.corners import detect_corners
from cvsflow.corners.grid import _subpix_window
from cvsflow.io.synth_out import PyAvVideoSink, VideoSink
from cvsflow.synth.effects import PTS_RATE_HZ
from cvsflow.synth.frames import FrameEffects
from cvsflow.synth.motion import make_hand_motion
from cvsflow.synth.render import _session_setup, realistic_truth
from cvsflow.synth.spec import parse_session_config

ROOT = Path(__file__).resolve().parents[1]


def session_cfg(name):
    for cfg in ("bench/uncertainty_sessions.yaml", "config/config.yaml"):
        s = yaml.safe_load((ROOT / cfg).read_text())["sessions"]
        if name in s:
            return copy.deepcopy(s[name])
    raise SystemExit(f"no session {name}")


def render(cfg, raster, sharp=False, supersample=1):
    """Frames (list of uint8 (H, W)) and truth of ``cfg`` with the realistic or legacy rasteriser.

    ``supersample`` s > 1: the realistic frames are rendered at s times the size (K scaled,
    pixel centres kept: c_hi = s c + (s - 1) / 2) and area-averaged back down."""
    spec = parse_session_config(cfg)
    rngs, _, renderer, _ = _session_setup(spec)
    if supersample > 1:
        hi = copy.deepcopy(cfg)
        cam, s = hi["synth"]["camera"], supersample
        cam.update(fx_px=s * cam["fx_px"], fy_px=s * cam["fy_px"],
                   cx_px=s * cam["cx_px"] + (s - 1) / 2, cy_px=s * cam["cy_px"] + (s - 1) / 2)
        hi["synth"]["image_size"] = [s * v for v in spec.image_size]
        spec_hi = parse_session_config(hi)
        renderer = _session_setup(spec_hi)[2]
    motion = make_hand_motion(rngs["motion"], spec.K, spec.image_size, spec.board.center_B(),
                              spec.effects.distance_m)
    truth, timeline, lighting, _ = realistic_truth(spec, rngs, motion)
    if sharp:
        truth = replace(truth, exposure_s=np.full_like(truth.exposure_s, 1e-6),
                        blur_px=np.zeros_like(truth.blur_px))
    rng = np.random.default_rng(12345)  # the same noise draws for both rasterisers
    frames = []
    for k in range(len(truth.t_s)):
        if raster == "realistic":
            fx = FrameEffects(hand=None, gain=float(truth.gain[k]),
                              analog_gain=float(truth.analog_gain[k]), wb_gains=truth.wb_gains[k])
            img = renderer.realistic_frame(motion, truth.t_s[k], truth.exposure_s[k],
                                           truth.blur_px[k], lighting, rng, fx)
            if supersample > 1:
                img = cv2.resize(img, tuple(spec.image_size), interpolation=cv2.INTER_AREA)
        else:
            img = renderer.video_frame(motion, truth.t_s[k], truth.exposure_s[k],
                                       truth.blur_px[k], lighting, rng)
        frames.append(img)
    return spec, truth, timeline, frames


def decode(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    return out


def through_writer(frames, writer, spec, timeline, tmp):
    """``frames`` encoded by ``writer`` ('mpeg4', 'legacy', 'png') and decoded again."""
    size = spec.image_size
    if writer == "png":
        return [cv2.imdecode(cv2.imencode(".png", f)[1], cv2.IMREAD_GRAYSCALE) for f in frames]
    path = Path(tmp) / f"{writer}.mp4"
    if writer in ("mpeg4", "mpeg4intra"):
        e = spec.effects
        with PyAvVideoSink(path, "mp4v", size, e.fps, crf=e.crf, quality=e.quality,
                           pts_rate_hz=PTS_RATE_HZ) as sink:
            if writer == "mpeg4intra":
                sink._stream.gop_size = 1  # every frame a key frame: no inter-frame prediction
            for f, pts in zip(frames, timeline.pts, strict=True):
                sink.write(f, pts)
    else:
        with VideoSink(path, spec.effects.fps, size, spec.video_quality) as sink:
            for f in frames:
                sink.write(f)
    out = decode(path)
    if len(out) != len(frames):
        raise RuntimeError(f"{path}: decoded {len(out)} of {len(frames)} frames")
    return out


def modes(uv_true, J6):
    """Unit mode vectors (2N,) of the common shift x, y, scale and rotation, and PnP's basis."""
    n = len(uv_true)
    c = uv_true - uv_true.mean(axis=0)
    ex = np.zeros((n, 2))
    ex[:, 0] = 1
    ey = np.zeros((n, 2))
    ey[:, 1] = 1
    sc = c.copy()
    rot = np.stack([-c[:, 1], c[:, 0]], axis=1)
    M = {k: (v.ravel() / np.linalg.norm(v)) for k, v in
         (("shift_x", ex), ("shift_y", ey), ("scale", sc), ("rotation", rot))}
    Q, _ = np.linalg.qr(J6)
    return M, Q


def analyse(detected, spec, truth, window_px, from_truth=False, from_s=0.0):
    """Per-frame corner errors of ``detected`` images against ``truth``: summary dict.

    ``from_truth``: plain ``cv2.cornerSubPix`` with half window ``window_px`` started at the
    true corners rounded to the pixel grid, instead of the detector. Frames captured before
    ``from_s`` are left out."""
    board = {"squares_x": spec.board.squares_x, "squares_y": spec.board.squares_y,
             "square_m": spec.board.square_m}
    p_B = spec.board.corners_B()
    rows, used_w, shift = [], [], []
    frame_idx = []
    for k, gray in enumerate(detected):
        if truth.t_s[k] < from_s:
            continue
        true = truth.corners_px[k]
        if from_truth:
            uv = None
            if np.isfinite(true).all():
                start = np.round(true).astype(np.float32).reshape(-1, 1, 2)
                uv = cv2.cornerSubPix(gray, start, (window_px, window_px), (-1, -1),
                                      SUBPIX_CRITERIA).reshape(-1, 2).astype(float)
        else:
            uv, _ = detect_corners(gray, board, subpix_window_px=window_px)
        if uv is None or not np.isfinite(uv).all() or not np.isfinite(true).all():
            continue
        e = uv - true
        if np.abs(e).max() > 3.0:  # a flip or a wrong grid: not corner noise
            continue
        used_w.append(window_px if from_truth else _subpix_window(uv, board, window_px))
        T = truth.T_C_B[k]
        rvec, _ = cv2.Rodrigues(T[:3, :3])
        _, jac = cv2.projectPoints(p_B, rvec, T[:3, 3], spec.K, spec.dist)
        M, Q = modes(true, jac[:, :6])
        ev = e.ravel()
        a = Q.T @ ev
        resid = ev - Q @ a
        rows.append({"absorbed": float(a @ a), "resid": float(resid @ resid),
                     "dof": 2 * len(e) - 6, **{m: float((v @ ev) ** 2) for m, v in M.items()},
                     "sq_px": float(np.median(np.linalg.norm(np.diff(true.reshape(
                         spec.board.ny, spec.board.nx, 2), axis=1), axis=2)))})
        shift.append(e.mean(axis=0))
        frame_idx.append(k)
    if not rows:
        return {"n_frames": 0}
    resid = sum(r["resid"] for r in rows)
    dof = sum(r["dof"] for r in rows)
    s2 = resid / dof
    out = {"n_frames": len(rows), "sigma_px": float(np.sqrt(s2)),
           "absorbed_per_dof": float(np.mean([r["absorbed"] for r in rows]) / 6 / s2)}
    for m in ("shift_x", "shift_y", "scale", "rotation"):
        out[m] = float(np.mean([r[m] for r in rows]) / s2)
    sh = np.array(shift)
    fi = np.array(frame_idx)
    consecutive = np.diff(fi) == 1
    ac = []
    for j in range(2):
        d = sh[:, j] - sh[:, j].mean()
        ac.append(float(np.sum(d[:-1][consecutive] * d[1:][consecutive])
                        / max(np.sum(d[:-1][consecutive] ** 2), 1e-30)))
    out["shift_lag1_ac"] = ac
    out["shift_mean_px"] = [float(v) for v in sh.mean(axis=0)]
    out["shift_rms_px"] = float(np.sqrt(np.mean(np.sum(sh ** 2, axis=1)) / 2))
    out["square_px_median"] = float(np.median([r["sq_px"] for r in rows]))
    out["window_used"] = sorted({int(w) for w in used_w})
    return out


def fmt(name, r):
    if not r.get("n_frames"):
        return f"{name:22s} no frames"
    return (f"{name:22s} n {r['n_frames']:3d} sq {r['square_px_median']:5.1f} px  w {r['window_used']}"
            f"  sigma {r['sigma_px']:.4f} px  absorbed/dof {r['absorbed_per_dof']:.2f}  shift x/y "
            f"{r['shift_x']:.2f}/{r['shift_y']:.2f}  scale {r['scale']:.2f}  rot {r['rotation']:.2f}"
            f"  shift ac1 {r['shift_lag1_ac'][0]:+.2f}/{r['shift_lag1_ac'][1]:+.2f}"
            f"  shift rms {r['shift_rms_px']:.4f} mean {r['shift_mean_px'][0]:+.4f}/"
            f"{r['shift_mean_px'][1]:+.4f} px")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("session")
    ap.add_argument("--duration-s", type=float, default=4.0)
    ap.add_argument("--distance-m", default=None)
    ap.add_argument("--raster", action="store_true")
    ap.add_argument("--windows", default=None)
    ap.add_argument("--writers", default="raw,png,mpeg4,legacy")
    ap.add_argument("--cache", default="/tmp/bench_codec_corners")
    ap.add_argument("--tag", default="")
    ap.add_argument("--supersample", type=int, default=1,
                    help="render at this many times the size and area-average down")
    ap.add_argument("--sharp", action="store_true", help="no motion blur (exposure 1 us)")
    ap.add_argument("--no-noise", action="store_true", help="no read or shot noise")
    ap.add_argument("--from-s", type=float, default=0.0,
                    help="score only frames from this time on (the u_* renders hold the board "
                         "still for their first 2 s)")
    ap.add_argument("--from-truth", action="store_true",
                    help="plain cornerSubPix from the rounded true corners, not the detector")
    a = ap.parse_args()
    cfg = session_cfg(a.session)
    cfg["synth"]["duration_s"] = a.duration_s
    if a.distance_m:
        cfg["synth"]["distance_m"] = [float(v) for v in a.distance_m.split(",")]
    # the realistic path needs an effect key; with none, give the fast preset's image size
    cfg["synth"].setdefault("image_size", [640, 480])
    if a.no_noise:
        cfg["synth"]["noise"] = {"read_sigma": 0.0, "shot_gain": 0.0}
    rasters = ["realistic", "legacy"] if a.raster else ["realistic"]
    writers = a.writers.split(",")
    windows = [5] if a.windows is None else [int(v) for v in a.windows.split(",")]
    results = {}
    first = None
    with tempfile.TemporaryDirectory() as tmp:
        for raster in rasters:
            spec, truth, timeline, frames = render(cfg, raster, a.sharp, a.supersample)
            print(f"{a.session} raster {raster}: {len(frames)} frames, video_quality "
                  f"{spec.video_quality}, mpeg4 quality {spec.effects.quality}", flush=True)
            if first is None:
                first = frames
            else:
                d = np.array([np.abs(x.astype(int) - y).max() for x, y in zip(first, frames, strict=True)])
                n_diff = sum(int(np.count_nonzero(x != y)) for x, y in zip(first, frames, strict=True))
                print(f"  rasterisers: max pixel difference {d.max()} grey levels, {n_diff} "
                      f"pixels differ over {len(frames)} frames", flush=True)
                results["raster_max_pixel_difference"] = int(d.max())
            for writer in writers:
                imgs = frames if writer == "raw" else through_writer(frames, writer, spec, timeline, tmp)
                if writer != "raw":
                    d = np.mean([np.mean((i.astype(float) - f) ** 2) for i, f in zip(imgs, frames, strict=True)])
                    print(f"  {writer}: pixel RMS change {np.sqrt(d):.3f} grey levels", flush=True)
                for w in windows if writer in ("raw", "mpeg4") else windows[-1:]:
                    name = f"{raster}/{writer}/w{w}"
                    results[name] = analyse(imgs, spec, truth, w, a.from_truth, a.from_s)
                    print(fmt(name, results[name]), flush=True)
    out = Path(a.cache) / f"{a.session}{a.tag}.yaml"
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(yaml.safe_dump(results, sort_keys=False))
    print(f"written {out}")


if __name__ == "__main__":
    sys.exit(main())
