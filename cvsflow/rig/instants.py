"""Corners of a camera not triggered with the others, moved to its rig frames' instants.

:func:`corners_at_instants` interpolates each corner's track in time (through three frames
where they are there, else linearly, or extrapolating at most half an interval), and
:func:`interpolation_error_ms` states the variance that interpolation adds (the next Newton
term of the interpolant, from the track's divided differences).
:func:`cvsflow.rig.poses.fused_rig_poses` fuses the moved views.
"""

from __future__ import annotations

import warnings

import numpy as np

from cvsflow.geometry import sample_period

#: How far (in ``max_gap_s``) the extra frame of :func:`interpolation_error_ms`'s fallback
#: divided difference may lie from the interpolant's nodes: next to a dropped frame the next
#: found one is two intervals away, and a divided difference stays an estimate of the
#: derivative with unequal spacing.
EXTRA_NODE_GAPS = 3.0


def _instant_nodes(t_s, t_target_s, max_gap_s):
    """The frames :func:`corners_at_instants` moves each frame's corners with.

    Returns
    -------
    moved, usable : ndarray of bool, shape (F,)
        Frames off their instant; those of them with a neighbour to move them with.
    w : ndarray, shape (F,)
        Weight of that neighbour j (0..1 interpolating, -0.5..0 extrapolating), 0 if none.
    j, k : ndarray of int, shape (F,)
        The neighbour, and the frame's other neighbour (``2 i - j``: the quadratic's third).
    third : ndarray of bool, shape (F,)
        Interpolated frames whose third frame is within ``max_gap_s``.
    """
    n = len(t_s)
    dt = t_target_s - t_s
    moved = np.abs(dt) > 1e-6
    w = np.zeros(n)
    j = np.arange(n)
    usable = np.zeros(n, bool)
    # the neighbour across the instant first; the one before it (extrapolating at most half
    # an interval) where the board was not found across it
    for side, w_lo, w_hi in ((1, 0.0, 1.0), (-1, -0.5, 0.0)):
        j_side = np.clip(np.arange(n) + side * np.sign(dt).astype(int), 0, max(n - 1, 0))
        gap = t_s[j_side] - t_s
        with np.errstate(divide="ignore", invalid="ignore"):
            w_side = np.where(gap != 0, dt / gap, np.nan)
        take = moved & ~usable & (np.abs(gap) <= max_gap_s) & (w_side >= w_lo) & (w_side <= w_hi)
        w, j, usable = np.where(take, w_side, w), np.where(take, j_side, j), usable | take
    i = np.arange(n)
    k = np.clip(2 * i - j, 0, max(n - 1, 0))  # f's other neighbour: j is i +- 1
    third = moved & usable & (w > 0.0) & (k != i) & (np.abs(t_s[k] - t_s) <= max_gap_s)
    return moved, usable, w, j, k, third


def corners_at_instants(uv, t_s, t_target_s, max_gap_s, quadratic=True):
    """One camera's corners moved to its rig frames' instants by interpolation in time.

    Parameters
    ----------
    uv : ndarray, shape (F, N, 2)
        The camera's found frames' corners in time order, px; NaN where not seen.
    t_s : ndarray, shape (F,)
        Their times on the Vicon clock, s.
    t_target_s : ndarray, shape (F,)
        The instant of the rig frame each belongs to, s.
    max_gap_s : float
        Longest interval between the two frames interpolated, s.
    quadratic : bool
        Interpolate a corner through three frames (f, its neighbour across the instant and
        its neighbour on the other side, Lagrange weights) where the third has it: linear
        interpolation misses the corner's image acceleration a by a tau (1 - tau) dt^2 / 2,
        comparable to the corner noise for a hand-held board at 25-30 fps. False, or no third
        frame within ``max_gap_s``: linear.

    Returns
    -------
    uv_at : ndarray, shape (F, N, 2)
        Frame f's corners at ``t_target_s[f]``: its own where the times agree to 1 us,
        otherwise interpolated between frame f and its neighbour on the other side of the
        instant, or, where the board was not found there, extrapolated from the neighbour on
        this side by at most half their interval; NaN where either frame lacks the corner,
        and for the whole frame where no neighbour within ``max_gap_s`` serves.
    noise_factor : ndarray, shape (F,)
        The moved corners' noise over one frame's, the root sum of the squared weights:
        ``sqrt((1 - w)^2 + w^2)`` for weight w of the neighbour when linear, the three
        Lagrange weights' where any corner of the frame was interpolated through three
        frames (their sum of squares is the larger); 1 where not moved.
    moved : ndarray of bool, shape (F,)
        Frames that needed interpolation.
    usable : ndarray of bool, shape (F,)
        Those of them that had a neighbour for it.
    """
    n = len(t_s)
    moved, usable, w, j, k, third = _instant_nodes(t_s, t_target_s, max_gap_s)
    uv_at = (1.0 - w)[:, None, None] * uv + w[:, None, None] * uv[j]
    factor = np.sqrt((1.0 - w) ** 2 + w**2)
    if quadratic and n >= 3:
        t0, t1, t2, tt = t_s, t_s[j], t_s[k], t_target_s
        with np.errstate(divide="ignore", invalid="ignore"):
            L = np.stack([(tt - t1) * (tt - t2) / ((t0 - t1) * (t0 - t2)),
                          (tt - t0) * (tt - t2) / ((t1 - t0) * (t1 - t2)),
                          (tt - t0) * (tt - t1) / ((t2 - t0) * (t2 - t1))])  # fmt: skip
        third &= np.isfinite(L).all(axis=0)
        L = np.where(third, L, 0.0)
        uv_q = L[0][:, None, None] * uv + L[1][:, None, None] * uv[j] + L[2][:, None, None] * uv[k]
        use_q = third[:, None] & np.isfinite(uv_q).all(axis=-1)
        uv_at = np.where(use_q[..., None], uv_q, uv_at)
        factor = np.where(use_q.any(axis=1), np.sqrt((L**2).sum(axis=0)), factor)
    uv_at[moved & ~usable] = np.nan
    return uv_at, factor, moved, usable


def interpolation_error_ms(uv, t_s, t_target_s, max_gap_s, sigma_px, half_window=3):
    """Mean square interpolation error of each frame's corners moved through three frames.

    The three-frame (quadratic) interpolant at the instant misses a corner by the next term of
    its Newton series, ``f[t_k, t_i, t_j, t_q] (t - t_k)(t - t_i)(t - t_j)``: the third divided
    difference of the track (nodes k, i, j of :func:`corners_at_instants` and the frame q
    beyond j) times the nodes' polynomial at the instant. Its mean square over the frame's
    corners and both axes, less what corner noise of ``sigma_px`` per axis puts into the
    difference (``sigma_px^2 omega^2 sum w^2``, w the four divided-difference weights), is the
    interpolation's variance per corner and axis at low frequencies. Hand tremor at 5-11 Hz
    is near the Nyquist frequency of a 25-30 fps camera, where the third difference falls
    short of the interpolation's error (by 1.2-1.7 in amplitude at 2.0-2.5 rad per frame):
    the variance is scaled by ``|E(w, tau)|^2 / |D(w, tau)|^2`` (at least 1), the ratio of the
    three-frame interpolation's error to the third difference's estimate of it for a sinusoid
    of w rad per frame at tau frames from frame i, w the track's dominant frequency over
    ``half_window`` frames either side from the power of its unit-step fourth and third
    differences (``4 sin^2(w / 2)`` their ratio, each less its noise share, 70 and 20
    ``sigma_px^2``).

    Parameters
    ----------
    uv, t_s, t_target_s, max_gap_s
        As :func:`corners_at_instants`.
    sigma_px : float
        Corner noise per axis, px.
    half_window : int
        Frames either side over which the track's dominant frequency is estimated.

    Returns
    -------
    ms_px2 : ndarray, shape (F,)
        Per frame the estimated interpolation variance per corner and axis, px^2; 0 where
        the frame was not moved or no four frames serve within ``max_gap_s``. A frame moved
        linearly or by extrapolation (:func:`corners_at_instants`: a block edge, a dropped
        frame) or through three frames without the fourth beyond j gets the next term of the
        interpolant it had, the divided difference taken with the frame beyond either end of
        its nodes, and the same frequency factor for its own nodes
        (:func:`_nyquist_factor_nodes`). The frequency is estimated from evenly spaced frames
        only.
    """
    n = len(t_s)
    out = np.zeros(n)
    if n < 4:
        return out
    i = np.arange(n)
    dt = t_target_s - t_s
    side = np.sign(np.where(np.abs(dt) > 1e-6, dt, 0.0)).astype(int)
    j, k, q = (np.clip(i + m * side, 0, n - 1) for m in (1, -1, 2))
    ok = (side != 0) & (k != i) & (q != j) & (j != i)
    ok &= (np.abs(t_s[i] - t_s[k]) <= max_gap_s) & (np.abs(t_s[j] - t_s[i]) <= max_gap_s)
    ok &= np.abs(t_s[q] - t_s[j]) <= max_gap_s
    ms, valid = _newton_remainder_ms(uv, t_s, t_target_s, (k, i, j), q, sigma_px)
    ok &= valid
    out[ok] = ms[ok]
    # the track's dominant frequency, rad per frame: none to speak of on fewer than 5 frames
    w = _dominant_frequency(uv, t_s, float(sigma_px), half_window) if n >= 5 else np.zeros(n)
    if n >= 5:
        tau = np.abs(dt) / np.where(j != i, np.abs(t_s[j] - t_s), np.inf)
        out *= _nyquist_factor(w, tau)
    # The others (a block edge or a dropped frame next to them): the next term of the
    # interpolant they had, with the frame beyond either end of its nodes as the extra one.
    moved, usable, _, j_used, k_used, third = _instant_nodes(t_s, t_target_s, max_gap_s)
    rest = moved & usable & ~ok
    lin = ~third
    candidates = (
        (third, (k_used, i, j_used), 2 * j_used - i, j_used),  # beyond j
        (third, (k_used, i, j_used), 2 * k_used - i, k_used),  # beyond k
        (lin, (i, j_used), 2 * j_used - i, j_used),
        (lin, (i, j_used), 2 * i - j_used, i),
    )
    for kind, used, extra, next_to in candidates:
        take = rest & kind & (extra >= 0) & (extra < n)
        extra = np.clip(extra, 0, n - 1)
        take &= np.abs(t_s[extra] - t_s[next_to]) <= EXTRA_NODE_GAPS * max_gap_s
        take &= np.all([extra != u for u in used], axis=0)
        if not take.any():
            continue
        ms_rest, valid = _newton_remainder_ms(uv, t_s, t_target_s, used, extra, sigma_px)
        take &= valid
        if n >= 5 and take.any():
            h = sample_period(t_s)
            pos = [(t_s[u] - t_s) / h for u in used]
            ms_rest = ms_rest * _nyquist_factor_nodes(
                w, pos, (t_s[extra] - t_s) / h, (t_target_s - t_s) / h)
        out[take] = ms_rest[take]
        rest &= ~take
    return out


def _newton_remainder_ms(uv, t_s, t_target_s, used, extra, sigma_px):
    """Mean square over a frame's corners of the next Newton term of the interpolant through the
    frames ``used`` (index arrays, one per node), its divided difference taken with the frame
    ``extra``, less the corner noise's share; and where that was computable."""
    nodes = (*used, extra)
    ts = [t_s[a] for a in nodes]
    with np.errstate(divide="ignore", invalid="ignore"):
        w = [1.0 / np.prod([ts[a] - ts[b] for b in range(len(nodes)) if b != a], axis=0)
             for a in range(len(nodes))]
        poly = np.prod([t_target_s - t_s[u] for u in used], axis=0)
        e = sum(w[a][:, None, None] * uv[nodes[a]] for a in range(len(nodes))) * poly[:, None, None]
        gain2 = poly**2 * sum(x**2 for x in w)
    has = np.isfinite(e).all(axis=-1)
    valid = has.any(axis=1) & np.isfinite(gain2)
    ms = (np.where(has[..., None], e, 0.0) ** 2).sum(axis=(1, 2)) / np.maximum(2 * has.sum(axis=1), 1)
    ms = np.maximum(ms - float(sigma_px) ** 2 * np.where(valid, gain2, 0.0), 0.0)
    return np.where(valid, ms, 0.0), valid


def _mean_square_at(d, n, start, half_window):
    """Mean square of difference rows ``d`` (row r centred at frame r + start) over the frames
    within ``half_window`` of each of ``n`` frames (NaN rows and corners skipped)."""
    sq = np.full(n, np.nan)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # rows left out (NaN) have no mean
        sq[start : start + len(d)] = np.nanmean(d**2, axis=(1, 2)) if d.size else np.nan
    ok = np.isfinite(sq)
    box = np.ones(2 * half_window + 1)
    return np.convolve(np.where(ok, sq, 0.0), box, "same") / np.maximum(np.convolve(ok, box, "same"), 1)


def _dominant_frequency(uv, t_s, sigma_px, half_window):
    """Each frame's dominant track frequency, rad per frame (0 where unknown):
    :func:`interpolation_error_ms`. Differences whose frames are not evenly spaced (a dropped
    frame inside) are left out: across a gap they mistake the gap for motion."""
    n = len(uv)
    step = np.diff(t_s)
    even = np.abs(step - np.median(step)) <= 0.1 * np.median(step)
    with np.errstate(invalid="ignore"):
        d3 = uv[3:] - 3 * uv[2:-1] + 3 * uv[1:-2] - uv[:-3]
        d4 = uv[4:] - 4 * uv[3:-1] + 6 * uv[2:-2] - 4 * uv[1:-3] + uv[:-4]
        d3[~(even[2:] & even[1:-1] & even[:-2])] = np.nan
        d4[~(even[3:] & even[2:-1] & even[1:-2] & even[:-3])] = np.nan
        p3 = _mean_square_at(d3, n, 1, half_window) - 20.0 * sigma_px**2
        p4 = _mean_square_at(d4, n, 2, half_window) - 70.0 * sigma_px**2
        w = 2.0 * np.arcsin(np.sqrt(np.clip(p4 / p3, 0.0, 4.0)) / 2.0)
    return np.where((p3 > 0) & np.isfinite(w), w, 0.0)


#: Below this track frequency (rad per frame) the Newton term's estimate of the interpolation
#: error is exact to within a few per cent and the ratio of two tiny numbers is left at 1.
LOW_FREQUENCY_RAD = 0.05


def _nyquist_factor_nodes(w, offsets, extra, tau):
    """``|E|^2 / |D|^2`` (at least 1) for interpolants through arbitrary nodes.

    For a sinusoid of w rad per frame, E is the interpolant's error at tau and D the next
    Newton term's estimate of it (divided difference with the node ``extra``). All positions
    are in frames from frame i.

    Parameters
    ----------
    w : ndarray, shape (F,)
    offsets : sequence of ndarray, shape (F,)
        The interpolant's nodes.
    extra : ndarray, shape (F,)
    tau : ndarray, shape (F,)

    Returns
    -------
    factor : ndarray, shape (F,)
    """
    nodes = [*offsets, extra]
    with np.errstate(divide="ignore", invalid="ignore"):
        E = -np.exp(1j * w * tau)
        for a, o in enumerate(offsets):
            L = np.prod([(tau - b) / (o - b) for c, b in enumerate(offsets) if c != a], axis=0)
            E = E + L * np.exp(1j * w * o)
        dd = sum(np.exp(1j * w * o) / np.prod([o - b for c, b in enumerate(nodes) if c != a], axis=0)
                 for a, o in enumerate(nodes))
        D = dd * np.prod([tau - o for o in offsets], axis=0)
        ratio = np.abs(E) ** 2 / np.abs(D) ** 2
    ok = np.isfinite(ratio) & (w >= LOW_FREQUENCY_RAD)
    return np.where(ok, np.maximum(ratio, 1.0), 1.0)


def _nyquist_factor(w, tau):
    """``|E(w, tau)|^2 / |D(w, tau)|^2`` (at least 1) per frame for the four-frame nodes
    (:func:`interpolation_error_ms`), w the track's frequency in rad per frame."""
    tau = np.where(np.isfinite(tau), tau, 0.0)
    # nodes at -1, 0, 1 frames (k, i, j), the instant at tau; the estimate's fourth node at 2
    E = (tau * (tau - 1) / 2 * np.exp(-1j * w) + (1 - tau**2) + tau * (tau + 1) / 2 * np.exp(1j * w)
         - np.exp(1j * w * tau))  # fmt: skip
    D = (np.exp(2j * w) - 3 * np.exp(1j * w) + 3 - np.exp(-1j * w)) / 6 * (tau + 1) * tau * (tau - 1)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.abs(E) ** 2 / np.abs(D) ** 2
    return np.where(np.isfinite(ratio), np.maximum(ratio, 1.0), 1.0)
