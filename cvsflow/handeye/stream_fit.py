"""Time offset, hand-eye and target pose from a camera's and its marker body's pose streams.

Inputs: the camera's pose in the target frame from a detector, ``T_B_C(t_cam)`` on the camera's
clock, and its marker body's from motion capture, ``T_W_Cm(t_mocap)`` on the motion capture's.
Unknowns: ``T_Cm_C``, ``T_W_B`` and ``dt_offset_s`` with ``t_mocap = t_camera + dt_offset_s``.
The model is :mod:`cvsflow.handeye.stream_model`'s. Steps of :func:`estimate_streams`:

1. The offset's start: the angular-speed cross-correlation, then the relative-rotation
   refinement (:mod:`cvsflow.handeye.stream_offset`).
2. Frames whose time plus the offset (plus a margin for it to move) falls outside the motion
   capture or in one of its gaps are left out and counted.
3. The closed form of ``cvsflow.optimise.solve_hand_eye`` on up to 200 frames spread in time.
4. The joint robust fit of the 13 parameters (:func:`cvsflow.optimise.levenberg_marquardt`,
   ``soft_l1`` at 1.345 whitened sigmas, the analytic Jacobian), the residuals' 6 x 6 weights re-estimated
   from the residuals until they settle.
5. Standard errors: a frame's detector error persists while the view changes slowly (0.3-5 s
   on the ETH sets), so independent-residual (Gauss-Newton) errors are 3-7 times too small.
   The stated errors are the cluster-robust sandwich over time blocks (CR2) with the
   neighbouring blocks' cross terms (:func:`cvsflow.optimise.covariances` with ``adjacent``);
   the block is twice the residuals' correlation length (:func:`block_length`). A sandwich
   from a few effective blocks is itself noisy: with ``nu`` its Satterthwaite degrees of freedom
   per parameter (:func:`cvsflow.metrics.cluster_dof`) the error of the estimate over its
   sandwich error is about Student t(nu), whose standard deviation is ``sqrt(nu / (nu - 2))``;
   the stated ``std`` is the sandwich's times that (per parameter, at least the Gauss-Newton
   error), so that +-2 std covers about 95 % whatever ``nu`` (bench/bench_streams_coverage.py).

Where the data cannot determine something the result says so instead of a number: ``dt`` when
the camera stream gives no angular speed, the correlation has no clear peak, the camera is
nearly still at its frames, or the fit fixes dt only to worse than ``max_dt_std_s`` (the fit
then holds dt at ``dt_fallback_s``); the hand-eye when the marker body turned about one axis
only.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from cvsflow.exceptions import OptimiseError, OverlapError
from cvsflow.geometry import PoseCurve, invert_T, make_T, sample_period
from cvsflow.handeye.closed_form import MIN_AXIS_SPREAD_DEG, closed_form_hand_eye, motion_axis_spread_deg
from cvsflow.handeye.stream_model import PARAM_NAMES, RESIDUAL_NAMES, StreamProblem, robust_scatter
from cvsflow.handeye.stream_offset import best_coarse_offset, frame_motion, refine_offset
from cvsflow.optimise import covariances, levenberg_marquardt, solve_hand_eye

log = logging.getLogger(__name__)

#: soft_l1 scale in whitened sigmas (Huber's 1.345: 95 % Gaussian efficiency).
SOFT_L1_SCALE = 1.345
#: Fewest camera frames inside the motion capture for a fit.
MIN_FRAMES = 10


@dataclass
class StreamsOptions:
    """Options of :func:`estimate_streams`.

    Attributes
    ----------
    estimate_dt : bool
        False: hold dt at ``dt_init_s`` (or ``dt_fallback_s``), reported as assumed.
    dt_init_s : float or None
        Start of the offset, s; default the cross-correlation's, refined.
    dt_fallback_s : float
        Offset held when dt is not observable (0: one clock), s.
    max_offset_s : float
        Cross-correlation lags searched, s.
    speed_baselines_s : tuple of float
        Angular-speed baselines tried in turn, s.
    min_quality : float
        Smallest accepted cross-correlation quality (0..1).
    max_dt_std_s : float
        Largest standard error of dt still reported as an estimate, s.
    min_speed_rad_s, min_speed_m_s : float
        A frame moves when the marker body turns or travels faster; dt needs 10 such frames.
    block_s : float or None
        Sandwich time block, s; default twice the residuals' correlation length.
    max_gap_s : float or None
        Longest motion-capture interval interpolated over, s (default 3 median intervals).
    weight_rounds : int
        Rounds of (weights from the residuals, robust fit).
    small_sample : bool
        State the sandwich's errors times ``sqrt(nu / (nu - 2))`` (module docstring); False:
        the sandwich's alone.
    """

    estimate_dt: bool = True
    dt_init_s: float | None = None
    dt_fallback_s: float = 0.0
    max_offset_s: float = 2.0
    speed_baselines_s: tuple = (0.1, 0.2, 0.4)
    min_quality: float = 0.3
    max_dt_std_s: float = 0.02
    min_speed_rad_s: float = 0.1
    min_speed_m_s: float = 0.05
    block_s: float | None = None
    max_gap_s: float | None = None
    weight_rounds: int = 3
    small_sample: bool = True


@dataclass
class StreamsResult:
    """Time offset and hand-eye from two pose streams, with standard errors and what is known.

    Attributes
    ----------
    dt_offset_s, dt_offset_std_s : float or None
        ``t_mocap = t_camera + dt_offset_s`` and its standard error, s; None when not
        observable (``observability["dt"]["reason"]``).
    dt_used_s : float
        The offset the hand-eye was fitted with (the estimate, or the one held), s.
    T_Cm_C, T_W_B : ndarray, shape (4, 4), or None
        Camera in its marker body; target in the motion-capture world, m. None when the
        hand-eye is not observable.
    std : dict
        Stated standard error per name of :data:`PARAM_NAMES` (rotations in rad as right
        perturbations: ``T_Cm_C_r*`` about C's axes, ``T_W_B_r*`` about B's; translations in m,
        ``T_Cm_C_*`` in Cm, ``T_W_B_*`` in W).
    std_gn, std_sandwich, dof : dict
        Per parameter: the independent-residual error, the block sandwich's, and its degrees
        of freedom.
    cov : ndarray, shape (P, P)
        Covariance of the fitted parameters (``param_names`` order) with the stated errors.
    param_names : tuple of str
    sigma : dict
        The residuals' robust scales per component in C (rad, m).
    observability : dict
        ``dt`` and ``hand_eye``: ``observable`` (bool), ``reason`` (str or None) and what was
        measured (motion at the frames, rotation-axis spread).
    counts : dict
        ``n_camera``, ``n_used``, ``n_outside_mocap``, ``n_in_mocap_gap``, ``n_outliers``
        (a whitened residual beyond 5), ``n_blocks``.
    offset : dict
        The coarse and refined offsets before the fit.
    block_s, corr_len_s : float
        The sandwich's block and the residuals' correlation length, s.
    residual_rms : dict
        RMS of the used frames' residuals per component (rad, m).
    t_ref_ns : int
        The epoch of the fit's float seconds (the first camera time).
    estimate : dict
        ``T_Cm_C``, ``T_W_B`` and ``dt_s`` as fitted, observable or not.
    scatter : ndarray, shape (6, 6), or None
        The residuals' robust 6 x 6 scatter in C (rad, m; :data:`RESIDUAL_NAMES` order): a
        frame's detector and motion-capture error together, as the fit weighted it.
    """

    dt_offset_s: float | None
    dt_offset_std_s: float | None
    dt_used_s: float
    T_Cm_C: np.ndarray | None
    T_W_B: np.ndarray | None
    std: dict
    std_gn: dict
    std_sandwich: dict
    dof: dict
    cov: np.ndarray
    param_names: tuple
    sigma: dict
    observability: dict
    counts: dict
    offset: dict
    block_s: float
    corr_len_s: float
    residual_rms: dict
    t_ref_ns: int
    estimate: dict = field(default_factory=dict)
    scatter: np.ndarray | None = None


def seconds_since(t_ns, t_ref_ns) -> np.ndarray:
    """int64 ns to float seconds since ``t_ref_ns`` (the difference exact, then one rounding).

    Parameters
    ----------
    t_ns : array_like of int64
    t_ref_ns : int

    Returns
    -------
    ndarray of float
    """
    return (np.asarray(t_ns, np.int64) - np.int64(t_ref_ns)).astype(float) / 1e9


def block_length(r_w, t_s, min_block_s=1.0, max_frac=0.1, factor=2.0, level=0.05, run=3):
    """The sandwich's time block: ``factor`` times the residuals' correlation length.

    The correlation length is the first lag (in frames, times the median frame interval) from
    which the mean autocorrelation of the whitened components stays below ``level`` for ``run``
    lags: a detector's error is a white part plus a slow one (the view changing), and the slow
    tail is what a block and its neighbours' cross terms must hold. Blocks are at least
    ``min_block_s`` and at most ``max_frac`` of the span (ten blocks at the least).

    Parameters
    ----------
    r_w : ndarray, shape (N, 6)
        Whitened residuals in time order.
    t_s : ndarray, shape (N,)
        Their times, s.
    min_block_s, max_frac, factor, level : float
    run : int

    Returns
    -------
    block_s : float
    corr_len_s : float
    """
    x = r_w - r_w.mean(axis=0)
    n = len(x)
    var = np.maximum((x**2).sum(axis=0), 1e-300)
    lags = np.arange(1, max(2, n // 4))
    acf = np.array([np.mean((x[:-k] * x[k:]).sum(axis=0) / var) for k in lags])
    below = acf < level
    L = next((int(lags[i]) for i in range(len(lags) - run + 1) if below[i : i + run].all()), len(lags))
    corr_len_s = L * sample_period(t_s)
    span = float(t_s[-1] - t_s[0])
    return float(min(max(min_block_s, factor * corr_len_s), max(max_frac * span, min_block_s))), corr_len_s


def _start(t_cam, T_B_C, curve, dt0, max_frames=200):
    """Closed-form T_Cm_C, T_W_B at offset dt0 from frames spread in time."""
    R_A, p_A, _, _, status = curve.at(t_cam + dt0)
    ok = np.flatnonzero(status == 0)
    pick = ok[np.unique(np.linspace(0, len(ok) - 1, min(max_frames, len(ok))).round().astype(int))]
    T_W_Cm = make_T(R_A[pick], p_A[pick])
    try:
        # T_Cm_W T_W_B = T_Cm_C T_C_B: solve_hand_eye's A X = Z B with A = T_Cm_W, B = T_C_B
        return solve_hand_eye(invert_T(T_W_Cm), invert_T(T_B_C[pick]))
    except OptimiseError as exc:
        log.warning("hand-eye start: the robot-world closed form failed (%s); Park's instead", exc)
        return closed_form_hand_eye(T_W_Cm, invert_T(T_B_C[pick]), "eye_in_hand", "park")


def _offset_start(t_cam, T_B_C, curve, opts: StreamsOptions):
    """dt to start from, whether to fit it, what the offset steps found and why dt is unknown."""
    info = {"coarse": None, "refined": None}
    reasons = []
    if not opts.estimate_dt:
        reasons.append("not estimated (estimate_dt is off)")
        return (opts.dt_init_s if opts.dt_init_s is not None else opts.dt_fallback_s), False, info, reasons
    if opts.dt_init_s is not None:
        return opts.dt_init_s, True, info, reasons
    R = T_B_C[:, :3, :3]
    coarse = best_coarse_offset(t_cam, R, curve, opts.speed_baselines_s, opts.min_quality, opts.max_offset_s)
    info["coarse"] = coarse
    if coarse["dt_s"] is None:
        reasons.append(coarse["reason"])
        return opts.dt_fallback_s, False, info, reasons
    refined = refine_offset(t_cam, R, curve, coarse["dt_s"])
    info["refined"] = {k: refined[k] for k in ("dt_s", "sigma_s", "n_pairs")}
    return (refined["dt_s"] if refined["dt_s"] is not None else coarse["dt_s"]), True, info, reasons


def stream_offset(t_cam_ns, T_B_C, t_mocap_ns, T_W_Cm, options: StreamsOptions | None = None) -> dict:
    """The offset :func:`estimate_streams` starts from, as it finds it (steps 1 of the module).

    Parameters
    ----------
    t_cam_ns, T_B_C, t_mocap_ns, T_W_Cm, options
        As :func:`estimate_streams`.

    Returns
    -------
    dict
        ``dt_s`` (the refined offset, else the coarse one; None when the cross-correlation
        finds none: ``reason`` says why), ``coarse`` and ``refined`` (the steps' results, as
        :class:`StreamsResult`'s ``offset``), ``reason`` (str or None).
    """
    opts = options or StreamsOptions()
    t_cam_ns = np.asarray(t_cam_ns, np.int64)
    t_ref = int(t_cam_ns[0])
    curve = PoseCurve(seconds_since(t_mocap_ns, t_ref), T_W_Cm, max_gap_s=opts.max_gap_s)
    search = replace(opts, dt_init_s=None, estimate_dt=True)
    t_cam = seconds_since(t_cam_ns, t_ref)
    dt, found, info, reasons = _offset_start(t_cam, np.asarray(T_B_C, float), curve, search)
    return {"dt_s": float(dt) if found else None, **info, "reason": "; ".join(reasons) or None}


def _frames_in_curve(t_cam, curve, dt, margin_s, t_cam_ns, t_mocap_ns, dt_text):
    """Frames inside the curve at dt +- margin (status per frame); an OverlapError naming both
    spans when fewer than MIN_FRAMES are."""
    st = np.maximum.reduce([curve.at(t_cam + dt + s)[4] for s in (-margin_s, 0.0, margin_s)])
    used = st == 0
    if used.sum() < MIN_FRAMES:
        raise OverlapError(
            f"hand-eye from pose streams: {int(used.sum())} of {len(t_cam)} camera poses fall inside "
            f"the motion capture at {dt_text} (camera {t_cam_ns[0] / 1e9:.3f}-{t_cam_ns[-1] / 1e9:.3f} s, "
            f"motion capture {t_mocap_ns[0] / 1e9:.3f}-{t_mocap_ns[-1] / 1e9:.3f} s on their clocks, "
            f"{int((st == 2).sum())} in its gaps); need {MIN_FRAMES}"
        )
    return st


def _robust_fit(prob: StreamProblem, rounds: int):
    """The robust fit with the residuals' weights re-estimated until they settle."""
    x = np.zeros(prob.n_params)
    S, prob.W = robust_scatter(prob.raw(x)[0])
    for _ in range(max(1, rounds)):
        x = prob.recentre(levenberg_marquardt(prob.fun, prob.jac, x, "soft_l1", SOFT_L1_SCALE, 200).x)
        r, st = prob.raw(x)
        if np.any(st != 0):  # the offset moved frames out of the curve: leave them out
            prob.keep(st == 0)
            r = r[st == 0]
        S_new, prob.W = robust_scatter(r)
        settled = np.all(np.abs(np.sqrt(np.diag(S_new) / np.diag(S)) - 1) < 0.05)
        S = S_new
        if settled:
            break
    prob.recentre(levenberg_marquardt(prob.fun, prob.jac, x, "soft_l1", SOFT_L1_SCALE, 200).x)
    return S


def _covariance(prob: StreamProblem, opts: StreamsOptions):
    """Stated, Gauss-Newton and sandwich standard errors, dof, the covariance, blocks."""
    x = np.zeros(prob.n_params)
    r, _, J = prob.raw(x, jac=True)
    r_w = r @ prob.W.T
    J_w = np.einsum("ij,njp->nip", prob.W, J)
    block_s, corr_len_s = block_length(r_w, prob.t_cam)
    block_s = float(opts.block_s) if opts.block_s is not None else block_s
    blocks = np.floor((prob.t_cam - prob.t_cam[0]) / block_s).astype(int)
    m, P = r_w.size, J_w.shape[2]
    c = covariances(J_w.reshape(m, P), r_w.ravel(), "soft_l1", SOFT_L1_SCALE, np.repeat(blocks, 6),
                    adjacent=True)  # fmt: skip
    se_gn = np.sqrt(np.diag(c.cov_gn))
    se_cl = np.sqrt(np.clip(np.diag(c.cov_cl), 0.0, None))
    # Student t(nu)'s standard deviation; nu <= 2.5 (one or two blocks carry the parameter)
    # is capped at the value of nu = 2.5
    factor = np.sqrt(np.maximum(c.dof, 2.5) / (np.maximum(c.dof, 2.5) - 2.0)) if opts.small_sample else 1.0
    se = np.maximum(se_gn, se_cl * factor)
    sd_cl = np.sqrt(np.clip(np.diag(c.cov_cl), 1e-300, None))
    cov = c.cov_cl / np.outer(sd_cl, sd_cl) * np.outer(se, se)
    return se, se_gn, se_cl, c.dof, cov, block_s, corr_len_s, int(c.n_clusters), r_w


def estimate_streams(t_cam_ns, T_B_C, t_mocap_ns, T_W_Cm, options: StreamsOptions | None = None,
                     t_ref_ns: int | None = None) -> StreamsResult:  # fmt: skip
    """Time offset, hand-eye and target pose from a camera's and a marker body's pose streams.

    Parameters
    ----------
    t_cam_ns : array_like of int64, shape (N,)
        Camera frame times, camera clock, ns (strictly increasing).
    T_B_C : ndarray, shape (N, 4, 4)
        Camera in the target frame B per frame (a detector's pose), m.
    t_mocap_ns : array_like of int64, shape (M,)
        Motion-capture sample times, its clock, ns (strictly increasing).
    T_W_Cm : ndarray, shape (M, 4, 4)
        Camera marker body in the motion-capture world W per sample, m (NaN: not tracked).
    options : StreamsOptions, optional
    t_ref_ns : int, optional
        Epoch of the internal float seconds (default the first camera time).

    Returns
    -------
    StreamsResult

    Raises
    ------
    OverlapError
        Fewer than 10 camera poses inside the motion capture (both spans named).
    OptimiseError
        Times not increasing, or no closed-form start.
    """
    opts = options or StreamsOptions()
    t_cam_ns, t_mocap_ns = np.asarray(t_cam_ns, np.int64), np.asarray(t_mocap_ns, np.int64)
    T_B_C = np.asarray(T_B_C, float)
    if len(t_cam_ns) < MIN_FRAMES or np.any(np.diff(t_cam_ns) <= 0):
        raise OptimiseError(f"camera pose stream: {len(t_cam_ns)} poses; expected at least {MIN_FRAMES} "
                            "in strictly increasing time")  # fmt: skip
    t_ref = int(t_cam_ns[0]) if t_ref_ns is None else int(t_ref_ns)
    t_cam = seconds_since(t_cam_ns, t_ref)
    curve = PoseCurve(seconds_since(t_mocap_ns, t_ref), T_W_Cm, max_gap_s=opts.max_gap_s)
    dt, fit_dt, offset, reasons = _offset_start(t_cam, T_B_C, curve, opts)
    margin = 2.0 * float(np.median(curve.h)) if fit_dt else 0.0
    st = _frames_in_curve(t_cam, curve, dt, margin, t_cam_ns, t_mocap_ns, f"dt = {dt:.3f} s")
    used = st == 0
    counts = {"n_camera": len(t_cam), "n_used": int(used.sum()), "n_outside_mocap": int((st == 1).sum()),
              "n_in_mocap_gap": int((st == 2).sum())}  # fmt: skip
    tu, Tu = t_cam[used], T_B_C[used]
    motion = frame_motion(tu, curve, dt, opts.min_speed_rad_s, opts.min_speed_m_s)
    if motion["n_moving"] < MIN_FRAMES:
        reasons.append(
            f"the camera is nearly still at its frames: {motion['n_moving']} of {len(tu)} move faster "
            f"than {np.degrees(opts.min_speed_rad_s):.1f} deg/s or {opts.min_speed_m_s} m/s (at most "
            f"{motion['max_speed_deg_s']:.2f} deg/s, {motion['max_speed_m_s']:.3f} m/s; need {MIN_FRAMES})"
        )
        if fit_dt:
            fit_dt, dt = False, opts.dt_init_s if opts.dt_init_s is not None else opts.dt_fallback_s
    R_u, p_u, _, _, _ = curve.at(tu + dt)
    spread = motion_axis_spread_deg(make_T(R_u, p_u))
    obs = {"dt": {"observable": fit_dt, "reason": None, "motion": motion},
           "hand_eye": {"observable": spread >= MIN_AXIS_SPREAD_DEG, "axis_spread_deg": spread,
                        "reason": None}}  # fmt: skip
    if not obs["hand_eye"]["observable"]:
        return _unobservable_hand_eye(obs, counts, offset, dt, fit_dt, reasons, t_ref)
    T_X0, T_Y0 = _start(tu, Tu, curve, dt)
    prob = StreamProblem(tu, Tu[:, :3, :3], Tu[:, :3, 3], curve, T_X0, T_Y0, dt, fit_dt=fit_dt)
    S = _robust_fit(prob, opts.weight_rounds)
    counts["n_used"] = len(prob.t_cam)
    se, se_gn, se_cl, dof, cov, block_s, corr_len_s, n_blocks, r_w = _covariance(prob, opts)
    counts.update(n_blocks=n_blocks, n_outliers=int((np.abs(r_w) > 5).any(axis=1).sum()))
    names = PARAM_NAMES if fit_dt else PARAM_NAMES[1:]
    std = dict(zip(names, se.tolist(), strict=True))
    if fit_dt and std["dt_offset_s"] > opts.max_dt_std_s:
        reasons.append(f"the data fix dt only to +-{std['dt_offset_s']:.3f} s (more than max_dt_std_s "
                       f"{opts.max_dt_std_s:g} s)")  # fmt: skip
        obs["dt"]["observable"] = False
    if not obs["dt"]["observable"]:
        obs["dt"].update(reason="; ".join(reasons) or "unknown", dt_held_s=float(prob.dt0))
        log.info("hand-eye from pose streams: dt not observable: %s", obs["dt"]["reason"])
    r = prob.raw(np.zeros(prob.n_params))[0]
    have_dt = obs["dt"]["observable"]
    return StreamsResult(
        dt_offset_s=float(prob.dt0) if have_dt else None,
        dt_offset_std_s=std["dt_offset_s"] if have_dt else None,
        dt_used_s=float(prob.dt0), T_Cm_C=prob.T_X0, T_W_B=prob.T_Y0, std=std,
        std_gn=dict(zip(names, se_gn.tolist(), strict=True)),
        std_sandwich=dict(zip(names, se_cl.tolist(), strict=True)),
        dof=dict(zip(names, dof.tolist(), strict=True)), cov=cov, param_names=names,
        sigma=dict(zip(RESIDUAL_NAMES, np.sqrt(np.diag(S)).tolist(), strict=True)), observability=obs,
        counts=counts, offset=offset, block_s=block_s, corr_len_s=corr_len_s,
        residual_rms=dict(zip(RESIDUAL_NAMES, np.sqrt(np.mean(r**2, axis=0)).tolist(), strict=True)),
        t_ref_ns=t_ref, estimate={"T_Cm_C": prob.T_X0, "T_W_B": prob.T_Y0, "dt_s": float(prob.dt0)},
        scatter=S,
    )  # fmt: skip


def _unobservable_hand_eye(obs, counts, offset, dt, fit_dt, reasons, t_ref) -> StreamsResult:
    """The result when the marker body's rotations cannot fix the hand-eye: nulls and reasons."""
    spread = obs["hand_eye"]["axis_spread_deg"]
    obs["hand_eye"]["reason"] = (f"the marker body's rotation axes spread only {spread:.1f} deg "
                                 f"(expected at least {MIN_AXIS_SPREAD_DEG:g} deg): T_Cm_C is not "
                                 "determined")  # fmt: skip
    extra = [f"no pose fit (the hand-eye is not observable): the angular-speed correlation's offset "
             f"{dt:.4f} s has no standard error"] if fit_dt else []  # fmt: skip
    obs["dt"].update(observable=False, dt_held_s=float(dt), reason="; ".join(reasons + extra))
    log.warning("hand-eye from pose streams: %s", obs["hand_eye"]["reason"])
    return StreamsResult(None, None, float(dt), None, None, {}, {}, {}, {}, np.zeros((0, 0)), (), {}, obs,
                         counts, offset, float("nan"), float("nan"), {}, t_ref)  # fmt: skip
