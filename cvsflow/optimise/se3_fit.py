"""What an se3 fit of one camera (:func:`cvsflow.optimise.se3.optimise_se3`) and of a rig
(:func:`cvsflow.rig.optimise_se3_rig`) share: the options, the body tracks, the robust solve and
the uncertainty part of the result.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import INTRINSIC_NAMES
from cvsflow.optimise.body_tracks import CAMERA_MOVING_SMOOTH_S, BodyTrack
from cvsflow.optimise.result import build_options
from cvsflow.optimise.se3_cov import DEFAULT_INTRINSIC_STD, fixed_intrinsic_std
from cvsflow.optimise.se3_lm import LOSSES, levenberg_marquardt

log = logging.getLogger(__name__)

#: Intrinsics freed by default.
DEFAULT_FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")


@dataclass(frozen=True)
class Se3Options:
    """How an se3 fit runs: the config's ``optimise.se3`` block (and the rig's).

    Attributes
    ----------
    free : sequence of str
        Intrinsics to estimate, from ``INTRINSIC_NAMES``; the others stay at the calibration.
    fit_dt : bool
        Refine the time offset (else held at the start).
    loss : {"soft_l1", "huber", "linear"}
        Robust loss on the corner residuals.
    f_scale_px : float
        Scale of the robust loss, px (residuals well below it count quadratically).
    max_nfev : int
        Most residual evaluations of the solver.
    corr_warn : float
        Warn when two estimates correlate beyond this (absolute value).
    cluster_s : float
        Length (s of video time) of the blocks of frames that are independent clusters in the
        cluster-robust covariance.
    camera_smooth_s : float
        Window (s) of the moving average of the camera body track before the static test
        (:func:`~cvsflow.optimise.body_tracks.smooth_track`); 0: the raw track.
    board_smooth_s : float
        Window (s) of the moving average of the board body track: a few mocap samples take the
        marker noise out of the interpolant's slope, which otherwise puts kinks in the cost as
        a function of dt at every mocap sample (300 Hz is a multiple of 30 fps).
    camera_static_tol : (float, float) or None
        (m, rad): a smoothed camera track this close to its mean over 95 % of the take is
        static and its mean pose is used for every frame
        (:func:`~cvsflow.optimise.body_tracks.is_static`); None: never.
    camera_moving_smooth_s : float or None
        Window (s) of the local quadratic of a camera track found moving
        (:func:`~cvsflow.optimise.body_tracks.smooth_track_local`); None:
        ``CAMERA_MOVING_SMOOTH_S``. A box window long enough to test stillness would flatten
        a moving camera's path (sinc(f w) of a motion of f Hz).
    solver : {"lm", "scipy"}
        ``lm``: Levenberg-Marquardt on the normal equations with the robust loss by iterative
        reweighting (one m x n product per iteration); ``scipy``:
        ``scipy.optimize.least_squares`` (TRF: an SVD of the m x n Jacobian per iteration).
        Both minimise the same robust cost.
    fit_line_delay : bool
        Estimate the rolling shutter's line delay (s per image row): corner k of frame i is
        compared with the mocap at ``t_i + dt + line_delay_s * v_ik`` (v_ik its row, px), as
        Kalibr's rolling-shutter model; False: every corner at ``t_i + dt``.
    line_delay_s : float
        The line delay's start (fitted) or its known value (held), s per row; 0 and
        ``fit_line_delay`` False is a global shutter.
    """

    free: tuple = DEFAULT_FREE
    fit_dt: bool = True
    loss: str = "soft_l1"
    f_scale_px: float = 1.0
    max_nfev: int = 100
    corr_warn: float = 0.95
    cluster_s: float = 1.0
    camera_smooth_s: float = 1.0
    board_smooth_s: float = 0.01
    camera_static_tol: tuple | None = (0.002, 0.002)
    camera_moving_smooth_s: float | None = None
    solver: str = "lm"
    fit_line_delay: bool = False
    line_delay_s: float = 0.0

    @classmethod
    def build(cls, options=None, label="se3", **overrides):
        """Options checked, with ``overrides`` (field names) applied and the defaults resolved.

        Parameters
        ----------
        options : Se3Options or dict, optional
            The starting options (a dict: the config block); default the class defaults.
        label : str
            Prefix of the error messages.
        **overrides
            Fields to change.

        Returns
        -------
        Se3Options

        Raises
        ------
        OptimiseError
            An unknown option, or a value out of its range.
        """
        opts = build_options(cls, options, overrides, label)
        opts._check(label)
        if opts.camera_moving_smooth_s is None:
            opts = replace(opts, camera_moving_smooth_s=CAMERA_MOVING_SMOOTH_S)
        return opts

    def _check(self, label):
        """Raise OptimiseError naming the first option out of its range."""
        if self.loss not in LOSSES:
            raise OptimiseError(f"{label}: loss {self.loss!r}; expected one of {LOSSES}")
        if self.solver not in ("lm", "scipy"):
            raise OptimiseError(f"{label}: solver {self.solver!r}; expected 'lm' or 'scipy'")
        if not self.f_scale_px > 0:
            raise OptimiseError(f"{label}: f_scale_px {self.f_scale_px!r}; expected > 0 px")
        bad = [f for f in self.free if f not in INTRINSIC_NAMES]
        if bad:
            raise OptimiseError(f"{label}: free {bad} unknown; expected names from {INTRINSIC_NAMES}")
        if not (np.isfinite(self.line_delay_s) and self.line_delay_s >= 0.0):
            raise OptimiseError(f"{label}: line_delay_s {self.line_delay_s!r}; expected a finite value "
                                ">= 0 s")

    def tracks(self, bodies, share=None):
        """The camera-marker and board-marker tracks of a bodies table, smoothed as these options say.

        Parameters
        ----------
        bodies : DataFrame
            bodies.parquet (native rate).
        share : cvsflow.optimise.se3_share.Se3Share, optional
            Tracks made once for the session's fits (of these ``bodies``).

        Returns
        -------
        cam, brd : BodyTrack
            T_W_Cm and T_W_Bm.
        """
        make = (lambda body, **o: BodyTrack.from_bodies(bodies, body, **o)) if share is None else share.track
        cam = make("camera", smooth_s=self.camera_smooth_s, static_tol=self.camera_static_tol,
                   moving_smooth_s=self.camera_moving_smooth_s)  # fmt: skip
        return cam, make("board", smooth_s=self.board_smooth_s)

    def summary(self, cam):
        """The options and the camera's state as the result records them."""
        return {
            "cluster_s": float(self.cluster_s),
            "camera_smooth_s": float(self.camera_smooth_s),
            "board_smooth_s": float(self.board_smooth_s),
            "camera_static": bool(cam.static),
            "camera_static_tol": None if self.camera_static_tol is None else list(self.camera_static_tol),
            "loss": self.loss,
            "f_scale_px": float(self.f_scale_px),
        }


def solve(model, x0, options, history_row, label="se3"):
    """Minimise a model's robust cost from x0, recording every residual evaluation.

    Parameters
    ----------
    model : Se3Model or RigModel
        ``residuals(x)`` (m,), px, and ``jacobian(x)`` (m, n).
    x0 : ndarray, shape (n,)
        Start.
    options : Se3Options
        ``loss``, ``f_scale_px``, ``max_nfev``, ``solver``.
    history_row : callable
        ``history_row(x, r, nfev) -> dict``: the row of ``iterations`` for one evaluation.
    label : str
        Prefix of messages.

    Returns
    -------
    sol : LMSolution or scipy OptimizeResult
        ``x``, ``cost``, ``nfev``, ``status``, ``message``.
    history : list of dict
        One row per residual evaluation.
    n_jacobians : int
    warnings : list of str
        A solver that stopped before converging (logged).

    Raises
    ------
    OptimiseError
        The solver diverged (a non-finite solution).
    """
    history, n_jac = [], [0]

    def fun(x):
        r = model.residuals(x)
        history.append(history_row(x, r, len(history)))
        return r

    def jac(x):
        n_jac[0] += 1
        return model.jacobian(x)

    if options.solver == "scipy":
        sol = least_squares(
            fun, x0, jac=jac, method="trf", loss=options.loss, f_scale=options.f_scale_px,
            x_scale="jac", max_nfev=options.max_nfev, xtol=1e-10, ftol=1e-12, gtol=1e-10,
        )  # fmt: skip
    else:
        sol = levenberg_marquardt(fun, jac, x0, options.loss, options.f_scale_px, options.max_nfev)
    if not np.isfinite(sol.x).all():
        raise OptimiseError(f"{label}: the solver diverged ({sol.message})")
    warnings = []
    if sol.status <= 0:
        warnings.append(f"{label}: solver stopped before converging: {sol.message}")
        log.warning(warnings[-1])
    return sol, history, n_jac[0], warnings


def fixed_std(camera, names, label, warnings):
    """1-sigma of the fixed intrinsics (camera.yaml's ``std``), a warning for every default taken.

    Parameters
    ----------
    camera : dict
        camera.yaml content.
    names : sequence of str
        The intrinsics held fixed.
    label : str
        Prefix of the warning.
    warnings : list of str
        Appended to (and logged) when a std is defaulted.

    Returns
    -------
    std : ndarray, shape (len(names),)
    defaulted : list of str
    """
    if not names:
        return np.zeros(0), []
    sd, defaulted = fixed_intrinsic_std(camera, names)
    if defaulted:
        warnings.append(
            f"{label} has no std for the fixed {defaulted}; their uncertainty is taken as "
            f"{[DEFAULT_INTRINSIC_STD[n] for n in defaulted]} (DEFAULT_INTRINSIC_STD)"
        )
        log.warning(warnings[-1])
    return sd, defaulted


def uncertainty_keys(names, x, pc):
    """The estimates and their standard errors and correlations, by parameter name.

    Parameters
    ----------
    names : sequence of str
        Parameter names.
    x : ndarray, shape (n,)
        The estimates.
    pc : dict
        :func:`cvsflow.optimise.se3_cov.parameter_covariance`'s output.

    Returns
    -------
    dict
        ``estimates``, ``std_errors`` (total), ``std_errors_data``, ``std_errors_fixed``,
        ``std_errors_gn``, ``std_errors_cluster`` (name -> float) and ``correlation``,
        ``correlation_total`` (``names``, ``matrix`` rounded to 6 digits).
    """
    def named(v):
        return {n: float(a) for n, a in zip(names, v, strict=True)}

    return {
        "estimates": named(x),
        "std_errors": named(pc["se"]),
        "std_errors_data": named(pc["se_data"]),
        "std_errors_fixed": named(pc["se_fixed"]),
        "std_errors_gn": named(pc["se_gn"]),
        "std_errors_cluster": named(pc["se_cl"]),
        "correlation": {"names": list(names), "matrix": np.round(pc["corr"], 6).tolist()},
        "correlation_total": {"names": list(names), "matrix": np.round(pc["corr_total"], 6).tolist()},
    }


def correlation_warnings(corr, names, corr_warn, label, expected=()):
    """Warnings (logged) for every pair of estimates correlated beyond ``corr_warn``.

    Parameters
    ----------
    corr : ndarray, shape (n, n)
        Correlation of the estimates (data only).
    names : sequence of str
        Parameter names, in the order of ``corr``.
    corr_warn : float
        Absolute correlation above which a pair is reported.
    label : str
        Prefix of the messages (``"se3"``).
    expected : collection of (str, str)
        Pairs whose correlation is known and harmless (``se3.EXPECTED_CORRELATIONS``), not reported.

    Returns
    -------
    warnings : list of str
    """
    out = []
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if (names[i], names[j]) in expected or (names[j], names[i]) in expected:
                continue
            if abs(corr[i, j]) > corr_warn:
                out.append(
                    f"{label}: {names[i]} and {names[j]} correlate at {corr[i, j]:+.3f} "
                    f"(|corr| > {corr_warn}): the data hardly separate them"
                )
                log.warning(out[-1])
    return out
