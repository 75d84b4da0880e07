"""Robust least squares for the ``se3`` method: the loss, its cost, Levenberg-Marquardt, and
the check that refuses a fit that explains nothing (:func:`refuse_implausible_fit`).

The cost is scipy's robust cost 0.5 sum c^2 rho((r/c)^2) (``scipy.optimize.least_squares``'s
``loss`` and ``f_scale``), minimised by Levenberg-Marquardt on the normal equations with the
loss by iterative reweighting (Triggs et al. 2000, sec. 4.3; Marquardt 1963). The narrow dense
Jacobian (m x ~22) makes the work per iteration one m x n product.
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import OptimiseError

#: Robust losses (scipy's names).
LOSSES = ("linear", "soft_l1", "huber")


def loss_weights(r, loss, f_scale):
    """psi(r) and psi'(r) of the robust loss rho(z), z = (r/c)^2 (scipy's definitions).

    Parameters
    ----------
    r : ndarray, shape (m,)
        Residuals, px.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale c, px.

    Returns
    -------
    psi : ndarray, shape (m,)
        rho'(z) r, the gradient weight of each residual.
    dpsi : ndarray, shape (m,)
        rho'(z) + 2 z rho''(z), the curvature weight, at least 1e-12.
    """
    z = (r / f_scale) ** 2
    if loss == "linear":
        return r, np.ones_like(r)
    if loss == "soft_l1":
        d1 = 1.0 / np.sqrt(1.0 + z)
        d2 = -0.5 * (1.0 + z) ** -1.5
    else:  # huber
        big = z > 1.0
        zs = np.where(big, z, 1.0)
        d1 = np.where(big, zs**-0.5, 1.0)
        d2 = np.where(big, -0.5 * zs**-1.5, 0.0)
    # cost = 0.5 sum c^2 rho(z): gradient row weight psi = rho'(z) r, curvature rho' + 2 z rho''
    return d1 * r, np.maximum(d1 + 2.0 * z * d2, 1e-12)


def robust_cost(r, loss, f_scale):
    """0.5 sum c^2 rho((r/c)^2), scipy's robust cost.

    Parameters
    ----------
    r : ndarray, shape (m,)
        Residuals, px.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale c, px.

    Returns
    -------
    cost : float
    """
    z = (r / f_scale) ** 2
    if loss == "linear":
        rho = z
    elif loss == "soft_l1":
        rho = 2.0 * (np.sqrt(1.0 + z) - 1.0)
    else:
        rho = np.where(z <= 1.0, z, 2.0 * np.sqrt(z) - 1.0)
    return float(0.5 * f_scale**2 * np.sum(rho))


def gram(J, w=None):
    """J^T diag(w) J without BLAS threads (which thrash on a shared machine).

    Parameters
    ----------
    J : ndarray, shape (m, n)
    w : ndarray, shape (m,), optional
        Row weights; default 1.

    Returns
    -------
    G : ndarray, shape (n, n)
    """
    if w is None:
        return np.einsum("mi,mj->ij", J, J, optimize=False)
    return np.einsum("mi,m,mj->ij", J, w, J, optimize=False)


class LMSolution:
    """The fields of scipy's OptimizeResult that optimise_se3 reads."""

    def __init__(self, x, cost, nfev, njev, status, message):
        self.x, self.cost, self.nfev, self.njev = x, cost, nfev, njev
        self.status, self.message = status, message


def levenberg_marquardt(fun, jac, x0, loss, f_scale, max_nfev, max_iter=100):
    """Robust Levenberg-Marquardt: IRLS weights, Marquardt-scaled damping, normal equations.

    Minimises 0.5 sum c^2 rho((r/c)^2) (scipy's robust cost). Each iteration: weights
    w = rho'(z) (Triggs et al. 2000, "Bundle adjustment - a modern synthesis", sec. 4.3),
    H = J^T W J, g = J^T W r, step from (H + lambda diag H) dx = -g (Marquardt 1963).

    Parameters
    ----------
    fun : callable
        x (n,) -> residuals (m,).
    jac : callable
        x (n,) -> Jacobian (m, n).
    x0 : array_like, shape (n,)
        Start.
    loss : {"linear", "soft_l1", "huber"}
    f_scale : float
        Loss scale, px.
    max_nfev : int
        Most residual evaluations.
    max_iter : int
        Most Jacobian evaluations (iterations).

    Returns
    -------
    LMSolution
        ``x``, ``cost``, ``nfev``, ``njev``, ``status`` (1 converged, 2 no decrease along the
        damped step, 0 a limit reached) and ``message``.
    """
    x = np.asarray(x0, float).copy()
    r = fun(x)
    nfev, njev = 1, 0
    cost = robust_cost(r, loss, f_scale)
    lam = 1e-3
    status, message = 0, "maximum number of iterations reached"
    for _ in range(max_iter):
        J = jac(x)
        njev += 1
        w = loss_weights(r, loss, f_scale)[0] / np.where(r == 0, 1.0, r)
        w = np.where(r == 0, 1.0, w)
        H = gram(J, w)
        g = np.einsum("mi,m->i", J, w * r, optimize=False)
        d = np.maximum(np.diag(H), 1e-300)
        accepted = False
        while nfev < max_nfev:
            try:
                dx = -np.linalg.solve(H + lam * np.diag(d), g)
            except np.linalg.LinAlgError:
                lam *= 10.0
                continue
            x_new = x + dx
            r_new = fun(x_new)
            nfev += 1
            cost_new = robust_cost(r_new, loss, f_scale) if np.isfinite(r_new).all() else np.inf
            if cost_new < cost:
                accepted = True
                break
            lam *= 4.0
            if lam > 1e12:
                break
        if not accepted:
            status = 2 if lam > 1e12 else 0
            message = "no cost decrease along the damped step" if status else "max_nfev reached"
            break
        decrease = cost - cost_new
        x, r, cost = x_new, r_new, cost_new
        lam = max(lam / 3.0, 1e-9)
        # converged: the step moves no parameter by more than 1e-6 of its own uncertainty scale
        step_sigma = np.abs(dx) * np.sqrt(d) / np.sqrt(max(2.0 * cost / max(len(r), 1), 1e-300))
        if decrease <= 1e-12 * cost or step_sigma.max() < 1e-6:
            status, message = 1, "converged (step below 1e-6 sigma or relative decrease < 1e-12)"
            break
    return LMSolution(x, cost, nfev, njev, status, message)


#: A fit whose median corner residual exceeds this (px) explains nothing: corner noise is
#: under 1 px on any camera, so the Vicon poses do not predict the board.
IMPLAUSIBLE_MEDIAN_PX = 10.0


def refuse_implausible_fit(f_px, r_px, who="se3"):
    """OptimiseError when a fit's focal lengths or residuals say it explains nothing.

    The stage's range checks (:func:`cvsflow.plausibility.results.check_se3_result`: focal lengths
    near the calibration, mountings, time offset) come after; this one sees the residuals,
    and also guards the held-out folds' and the rig's fits.

    Parameters
    ----------
    f_px : sequence of float
        Fitted fx, fy, px.
    r_px : ndarray
        The fit's corner residuals, px.
    who : str
        Prefix of the message (``"se3"``, ``"se3 rig: camera 1"``).

    Returns
    -------
    None

    Raises
    ------
    OptimiseError
        A focal length not finite and positive, or a median residual above
        ``IMPLAUSIBLE_MEDIAN_PX``.
    """
    why = (" The corners and the Vicon poses do not agree: check the board (squares_x, "
           "squares_y, square_m), which Vicon body is the camera and which the board, the sync "
           "offset, and that the calibration is this camera's.")
    for name, f in zip(("fx", "fy"), f_px, strict=True):
        if not (np.isfinite(f) and f > 0):
            raise OptimiseError(f"{who}: the fit took {name} to {f:.4g} px." + why)
    med = float(np.median(np.abs(r_px)))
    if not med <= IMPLAUSIBLE_MEDIAN_PX:
        raise OptimiseError(
            f"{who}: after the fit the median corner residual is {med:.3g} px (more than "
            f"{IMPLAUSIBLE_MEDIAN_PX:g} px)." + why
        )
