"""The demo session's images: per-frame effects, the lighting drift and the renderer of stills and frames.

Pure functions of the session spec (:mod:`cvsflow.synth.spec`) and the true poses (no file
I/O); ``cvsflow.synth.render.render_session`` writes the images with ``cvsflow.io.synth_out``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cvsflow.synth.board_image import (
    BoardTexture,
    board_roi,
    make_board_texture,
    render_board,
    render_board_region,
)
from cvsflow.synth.effects import SKIN_BGR
from cvsflow.synth.imaging import expose, make_background, undistortion_grid, vignetting
from cvsflow.synth.motion import board_poses
from cvsflow.synth.spec import FOCUS_DEPTH_M, SynthSpec


@dataclass(frozen=True)
class FrameEffects:
    """Per-frame state of the realistic effects."""

    hand: BoardTexture | None  # hand texture of the current grip, None without a hand
    gain: float  # scene light x exposure x analog gain, relative to the reference
    analog_gain: float
    wb_gains: np.ndarray  # (3,) B, G, R


ILLUMINANT_BGR = np.array([0.92, 1.0, 1.06])  # slightly warm indoor light, per channel


@dataclass(frozen=True)
class Lighting:
    """Slow drifts of the scene lighting (global gain, offset, a soft gradient)."""

    drift: object  # SineSum with 4 channels

    def at(self, t_s):
        """(gain, offset, gradient_x, gradient_y) at one time: grey levels and fractions."""
        d = self.drift(np.array([t_s]))[0]
        return 215.0 * (1.0 + 0.12 * d[0]), 12.0 + 5.0 * d[1], 0.15 * d[2], 0.15 * d[3]


class Renderer:
    """Pre-computed camera, texture and background; renders stills and video frames.

    Parameters
    ----------
    spec : SynthSpec
    rng_background : numpy.random.Generator
        For the static cluttered background of the video and the pale one of the stills.
    markers_B : ndarray, shape (M, 3), optional
        Board markers in B (metres), drawn on the sheet where they lie on it.
    """

    def __init__(self, spec: SynthSpec, rng_background, markers_B=None):
        self.spec = spec
        size = spec.image_size
        self.xy_n = undistortion_grid(spec.K, spec.dist, size)
        self.texture: BoardTexture = make_board_texture(spec.board, markers_B=markers_B)
        self.background = make_background(rng_background, size)
        self.background_still = make_background(rng_background, size, n_rects=8, light=True)
        self.shading = vignetting(size, spec.K)
        width, height = size
        u, v = np.meshgrid(
            np.linspace(-0.5, 0.5, width, dtype=np.float32),
            np.linspace(-0.5, 0.5, height, dtype=np.float32),
        )
        self.ramp_u, self.ramp_v = u, v

    def board_layer(self, T_C_B_sub):
        """Mean of the board layer over sub-frame poses (N, 4, 4): motion blur."""
        layers = [
            render_board(T, self.texture, self.xy_n, self.spec.K, self.spec.dist)
            for T in T_C_B_sub
        ]
        return np.mean(layers, axis=0) if len(layers) > 1 else layers[0]

    def compose(self, layer, background, gain, offset, grad_u, grad_v, depth_m, rng):
        """Composite the board over the background, light it and expose it (uint8)."""
        reflectance = layer[..., 0] + (1.0 - layer[..., 1]) * background
        shading = self.shading * (1.0 + grad_u * self.ramp_u + grad_v * self.ramp_v)
        defocus_px = 0.5 + 1.5 * abs(1.0 / max(depth_m, 0.3) - 1.0 / FOCUS_DEPTH_M)
        return expose(
            reflectance * shading, gain, offset, defocus_px, self.spec.image_noise_sigma, rng
        )

    def still(self, T_C_B, rng):
        """A calibration still (uint8, 480 x 640): pale background, steady light, slight blur."""
        layer = self.board_layer(T_C_B[None])
        return self.compose(
            layer, self.background_still, 220.0, 10.0, 0.05, -0.05, T_C_B[2, 3], rng
        )

    def realistic_frame(self, motion, t_s, exposure_s, blur_px, lighting: Lighting, rng, fx):
        """A video frame with the realistic effects (``fx``: ``FrameEffects``), uint8 (H, W[, 3]).

        Under a rolling shutter the image is rendered in bands of ``band_rows`` rows, each
        with the board (and the hand) at the band's own capture time t_s + row * line_delay_s,
        and motion blur sampled per band over the exposure.
        """
        e = self.spec.effects
        width, height = e.image_size
        n_sub = int(np.clip(np.ceil(blur_px / 1.5) + 1, 1, 10))
        offsets = exposure_s * ((np.arange(n_sub) + 0.5) / n_sub - 0.5)
        if e.line_delay_s > 0.0:
            starts = np.arange(0, height, e.band_rows)
            stops = np.minimum(starts + e.band_rows, height)
            t_band = t_s + 0.5 * (starts + stops - 1) * e.line_delay_s
        else:
            starts, stops, t_band = np.array([0]), np.array([height]), np.array([t_s])
        T_all = board_poses(motion, (t_band[:, None] + offsets[None]).ravel()).reshape(
            len(t_band), n_sub, 4, 4
        )
        layers = [(self.texture, np.zeros((height, width, 2), np.float32))]
        if fx.hand is not None:
            layers.append((fx.hand, np.zeros((height, width, 2), np.float32)))
        K, dist = self.spec.K, self.spec.dist
        for b in range(len(t_band)):
            for j in range(n_sub):
                T = T_all[b, j]
                for texture, acc in layers:
                    roi = board_roi(T, texture, K, dist, (width, height))
                    if roi is None:
                        continue
                    x0, y0, x1, y1 = roi
                    y0, y1 = max(y0, int(starts[b])), min(y1, int(stops[b]))
                    if y1 <= y0:
                        continue
                    acc[y0:y1, x0:x1] += render_board_region(T, texture, self.xy_n, K, (x0, y0, x1, y1))
        board = layers[0][1] / np.float32(n_sub)
        grey = board[..., 0] + (1.0 - board[..., 1]) * self.background
        hand_alpha = layers[1][1][..., 1] / np.float32(n_sub) if fx.hand is not None else None
        gain, offset, grad_u, grad_v = lighting.at(t_s)
        shading = self.shading * (1.0 + grad_u * self.ramp_u + grad_v * self.ramp_v)
        if e.colour:
            refl = np.repeat(grey[..., None], 3, axis=2)
            if hand_alpha is not None:
                a = hand_alpha[..., None]
                refl = a * SKIN_BGR + (1.0 - a) * refl
            radiance = refl * shading[..., None]
            channel_gain = (gain * fx.gain * fx.wb_gains * ILLUMINANT_BGR).astype(np.float32)
        else:
            if hand_alpha is not None:
                hand = layers[1][1][..., 0] / np.float32(n_sub)
                grey = hand + (1.0 - hand_alpha) * grey
            radiance = grey * shading
            channel_gain = gain * fx.gain
        depth_m = float(T_all[len(t_band) // 2, n_sub // 2, 2, 3])
        defocus_px = e.defocus_base_px + e.defocus_px_m * abs(1.0 / max(depth_m, 0.3) - 1.0 / e.focus_m)
        return expose(
            radiance.astype(np.float32), channel_gain, offset, defocus_px, e.read_sigma, rng,
            shot_gain=e.shot_gain, analog_gain=fx.analog_gain,
        )

    def video_frame(self, motion, t_s, exposure_s, blur_px, lighting: Lighting, rng):
        """A video frame at container time ``t_s`` (mid-exposure), uint8 480 x 640.

        The exposure is sampled with about one sub-frame per 1.5 px of corner travel.
        """
        n_sub = int(np.clip(np.ceil(blur_px / 1.5) + 1, 1, 10))
        t_sub = t_s + exposure_s * ((np.arange(n_sub) + 0.5) / n_sub - 0.5)
        T_sub = board_poses(motion, t_sub)
        layer = self.board_layer(T_sub)
        gain, offset, grad_u, grad_v = lighting.at(t_s)
        depth_m = float(T_sub[n_sub // 2, 2, 3])
        return self.compose(layer, self.background, gain, offset, grad_u, grad_v, depth_m, rng)
