"""Hand-eye refinement on the corner reprojection error, with its standard errors.

H, G (and optionally fx, fy, cx, cy, distortion) minimising the corner reprojection error over
all stills, ``scipy.optimize.least_squares`` with the analytic Jacobian; projection and its
derivatives from :mod:`cvsflow.geometry.camera`. By default the carrier poses are not exact: each
still's pose error (a turn about the carrier origin and a shift) is an unknown with a zero-mean
isotropic prior, the corner, rotation and position sigmas estimated together (Foerstner's
variance components). Standard errors: ``N^-1`` of the whitened problem, plus the fixed
intrinsics' std when the camera gives it; the leave-one-out RMS of each still and a
delete-one-still jackknife.

Frames and modes are :mod:`cvsflow.handeye.closed_form`'s. Rotation errors are local:
``R = R_hat @ expm([w]x)``, w about the axes of the child frame (C for ``T_Cm_C`` and ``T_W_C``,
B for ``T_W_B`` and ``T_Bm_B``); translations in the parent.
"""

from __future__ import annotations

import logging

import numpy as np
from scipy.optimize import least_squares

from cvsflow.exceptions import InputError
from cvsflow.geometry import INTRINSIC_NAMES, project_points_jac, right_jacobian_SO3
from cvsflow.geometry import transforms as tf
from cvsflow.handeye.closed_form import MIN_STILLS, carrier_chain
from cvsflow.optimise import covariances

log = logging.getLogger(__name__)


def p_G_of(T_G, p_B):
    """The board corners in G's parent frame (W eye-in-hand, Bm eye-to-hand), (P, 3).

    Parameters
    ----------
    T_G : ndarray, shape (4, 4)
        The target G (``T_W_B`` or ``T_Bm_B``), m.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.

    Returns
    -------
    ndarray, shape (P, 3)
        ``T_G`` applied to ``p_B``, m.
    """
    return p_B @ T_G[:3, :3].T + T_G[:3, 3]


class _Model:
    """Corner residuals of ``T_C_B,i = inv(H) A_i G`` and their Jacobian, whitened.

    x = [w_H (3, rad), t_H (3, m), w_G (3, rad), t_G (3, m), free intrinsics (k),
    then with ``pose_noise`` one [rho_i (3, rad), tau_i (3, m)] per still], with
    R_H = R0_H expm([w_H]x), R_G = R0_G expm([w_G]x) and the carrier pose of still i taken as
    R_W_X,i = expm([rho_i]x) R_W_X,i (a turn about the carrier's origin), t_W_X,i + tau_i.
    Residuals: corner errors / sigma_px of the corners each still shows (NaN in ``uv``: not
    seen, an AprilGrid's or ChArUco's partial view), then rho / sigma_rot_rad and tau /
    sigma_pos_m (the carrier poses' errors as unknowns with zero-mean priors: errors in
    variables).
    """

    def __init__(self, T_W_X, mode, uv, p_B, T0_H, T0_G, intr0, free, pose_noise=False,
                 sigmas=(1.0, 1e-3, 1e-3)):  # fmt: skip
        self.T_W_X, self.mode = np.asarray(T_W_X, float), mode
        self.uv, self.p_B = uv, p_B
        self.R0_H, self.R0_G = T0_H[:3, :3], T0_G[:3, :3]
        self.x0_pose = np.concatenate([np.zeros(3), T0_H[:3, 3], np.zeros(3), T0_G[:3, 3]])
        self.intr0 = np.asarray(intr0, float)
        self.free = np.array([n in free for n in INTRINSIC_NAMES])
        self.k = 12 + int(self.free.sum())
        self.pose_noise = bool(pose_noise)
        self.sigma_px, self.sigma_pos_m, self.sigma_rot_rad = sigmas
        n = len(uv)
        self.seen = np.isfinite(uv).all(axis=2)  # (n, P)
        m = 2 * int(self.seen.sum())
        # row groups of the residual vector: corners, rho priors, tau priors
        self.groups = {"corners": slice(0, m)}
        if self.pose_noise:
            self.groups["rot"] = slice(m, m + 3 * n)
            self.groups["pos"] = slice(m + 3 * n, m + 6 * n)

    def x0(self):
        delta = np.zeros(6 * len(self.uv)) if self.pose_noise else np.zeros(0)
        return np.concatenate([self.x0_pose, self.intr0[self.free], delta])

    def unpack(self, x):
        T_H = tf.make_T(self.R0_H @ tf.R_from_rvec(x[0:3]), x[3:6])
        T_G = tf.make_T(self.R0_G @ tf.R_from_rvec(x[6:9]), x[9:12])
        intr = self.intr0.copy()
        intr[self.free] = x[12:self.k]
        return T_H, T_G, intr

    def carrier(self, x, rows=slice(None)):
        """The carrier poses the model uses (with the estimated errors removed), (n, 4, 4)."""
        T = self.T_W_X[rows]
        if not self.pose_noise:
            return T
        d = x[self.k:].reshape(-1, 6)[rows]
        return tf.make_T(tf.R_from_rvec(d[:, :3]) @ T[:, :3, :3], T[:, :3, 3] + d[:, 3:])

    def _project(self, A, T_H, T_G, intr, want_jac=False):
        K = np.array([[intr[0], 0.0, intr[2]], [0.0, intr[1], intr[3]], [0.0, 0.0, 1.0]])
        R_H = T_H[:3, :3]
        p_G = p_G_of(T_G, self.p_B)
        p_A = np.einsum("nij,pj->npi", A[:, :3, :3], p_G) + A[:, None, :3, 3]
        p_C = (p_A - T_H[:3, 3]) @ R_H  # R_H^T (p_A - t_H), (n, P, 3)
        uv, J_p, J_i = project_points_jac(p_C, K, intr[4:])
        return (uv, p_C, J_p, J_i) if want_jac else uv

    def project(self, x):
        T_H, T_G, intr = self.unpack(x)
        return self._project(carrier_chain(self.carrier(x), self.mode), T_H, T_G, intr)

    def residuals(self, x):
        r = [(self.project(x) - self.uv)[self.seen].ravel() / self.sigma_px]
        if self.pose_noise:
            d = x[self.k:].reshape(-1, 6)
            r += [d[:, :3].ravel() / self.sigma_rot_rad, d[:, 3:].ravel() / self.sigma_pos_m]
        return np.concatenate(r)

    def jacobian(self, x):
        T_H, T_G, intr = self.unpack(x)
        A = carrier_chain(self.carrier(x), self.mode)
        _, p_C, J_p, J_i = self._project(A, T_H, T_G, intr, want_jac=True)
        n, P = p_C.shape[:2]
        J = np.zeros((n, P, 2, len(x)))
        R_H, R_G = T_H[:3, :3], T_G[:3, :3]
        # d p_C / d w_H = [p_C]x Jr(w_H); d p_C / d t_H = -R_H^T
        J[..., 0:3] = J_p @ (tf.skew(p_C) @ right_jacobian_SO3(x[0:3]))
        J[..., 3:6] = J_p @ (-R_H.T)
        # d p_C / d p_G = R_H^T R_A; d p_G / d w_G = -R_G [p_B]x Jr(w_G); d p_G / d t_G = I
        M = np.einsum("ji,njk->nik", R_H, A[:, :3, :3])  # (n, 3, 3)
        d_pG_dw = -R_G @ tf.skew(self.p_B) @ right_jacobian_SO3(x[6:9])  # (P, 3, 3)
        J_pG = np.einsum("npij,njk->npik", J_p, M)  # (n, P, 2, 3)
        J[..., 6:9] = np.einsum("npij,pjk->npik", J_pG, d_pG_dw)
        J[..., 9:12] = J_pG
        J[..., 12:self.k] = J_i[..., self.free]
        if self.pose_noise:
            # carrier of still i: R' = expm([rho]x) R_W_X, t' = t_W_X + tau; Jl the left
            # Jacobian of SO(3), Jl(rho) = Jr(rho)^T
            d = x[self.k:].reshape(-1, 6)
            T_X = self.carrier(x)
            Jl = np.swapaxes(np.stack([right_jacobian_SO3(r) for r in d[:, :3]]), 1, 2)
            J_pA = J_p @ R_H.T  # (n, P, 2, 3): d uv / d p_A
            if self.mode == "eye_to_hand":  # p_A = R' p_G + t'
                u = np.einsum("nij,pj->npi", T_X[:, :3, :3], p_G_of(T_G, self.p_B))
                dA_drho = -tf.skew(u) @ Jl[:, None]
                dA_dtau = np.broadcast_to(np.eye(3), (n, 1, 3, 3))
            else:  # p_A = R'^T (p_G - t')
                v = p_G_of(T_G, self.p_B)[None] - T_X[:, None, :3, 3]
                Rt = np.swapaxes(T_X[:, :3, :3], 1, 2)[:, None]
                dA_drho = Rt @ tf.skew(v) @ Jl[:, None]
                dA_dtau = -np.broadcast_to(Rt, (n, 1, 3, 3))
            cols = self.k + 6 * np.arange(n)
            for j in range(3):
                J[np.arange(n), :, :, cols + j] = (J_pA @ dA_drho[..., j : j + 1])[..., 0]
                J[np.arange(n), :, :, cols + 3 + j] = (J_pA @ dA_dtau[..., j : j + 1])[..., 0]
        J = J[self.seen].reshape(-1, len(x)) / self.sigma_px
        if self.pose_noise:
            prior = np.zeros((6 * n, len(x)))
            k3 = np.arange(3 * n)
            rot_cols = self.k + 6 * (k3 // 3) + k3 % 3
            prior[k3, rot_cols] = 1.0 / self.sigma_rot_rad
            prior[3 * n + k3, rot_cols + 3] = 1.0 / self.sigma_pos_m
            J = np.vstack([J, prior])
        return J

    def jacobian_fixed(self, x):
        """Whitened derivatives of the residuals w.r.t. the fixed intrinsics, (m, 9 - k)."""
        T_H, T_G, intr = self.unpack(x)
        A = carrier_chain(self.carrier(x), self.mode)
        J_i = self._project(A, T_H, T_G, intr, want_jac=True)[3][..., ~self.free]
        J = J_i[self.seen].reshape(-1, int((~self.free).sum())) / self.sigma_px
        n_prior = 6 * len(self.uv) if self.pose_noise else 0
        return np.vstack([J, np.zeros((n_prior, J.shape[1]))])

    def still_rms(self, x):
        e2 = np.sum((self.project(x) - self.uv) ** 2, axis=-1)  # NaN where not seen
        return np.sqrt(np.nanmean(e2, axis=1))


def _intrinsics_vector(camera):
    K = np.asarray(camera["K"], float)
    dist = np.asarray(camera.get("dist", np.zeros(5)), float).ravel()
    if K.shape != (3, 3) or dist.size != 5:
        raise InputError(f"camera: K {K.shape}, dist {dist.shape}; expected (3, 3) and 5 values")
    return np.concatenate([[K[0, 0], K[1, 1], K[0, 2], K[1, 2]], dist])


#: Variance-component iterations (Foerstner 1979) and their stop: every factor within 1e-2.
VCE_MAX_ITER = 40
VCE_TOL = 1e-2


#: Floors of the estimated carrier-pose sigmas (m, rad): below them the prior is exact anyway.
SIGMA_FLOOR = {"pos": 1e-7, "rot": 1e-8}


def refine_hand_eye(uv_px, p_B, T_W_X, camera, T0_H, T0_G, mode="eye_in_hand",
                    free_intrinsics=(), pose_noise=True, pose_sigma_m=None, pose_sigma_rad=None):
    """Least-squares H, G (and the free intrinsics) by corner reprojection over all stills.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px; NaN rows: corners the still does not show.
    p_B : ndarray, shape (P, 3)
        The corners in B, metres.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier in world per still, metres.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start (and the values of fixed intrinsics).
    T0_H, T0_G : ndarray, shape (4, 4)
        Start, e.g. from :func:`closed_form_hand_eye`.
    mode : str
    free_intrinsics : sequence of str
        Names among ``fx fy cx cy k1 k2 p1 p2 k3`` to refine; empty keeps the camera fixed.
    pose_noise : bool
        Model the carrier poses' errors (a rotation about the carrier origin and a translation
        per still, zero-mean, isotropic) as unknowns with priors; without it the carrier poses
        are taken as exact and only the corners carry noise.
    pose_sigma_m, pose_sigma_rad : float, optional
        The priors' standard deviations; each one not given is estimated from the data with
        the corner sigma (variance components).

    Returns
    -------
    dict
        ``T_H``, ``T_G`` (4, 4), ``intrinsics`` (9,), ``cov`` (n, n) of ``param_names``
        (rotations as local errors about the solution's child axes, rad; translations m),
        including the fixed intrinsics' uncertainty when ``camera["std"]`` gives it (names in
        ``intrinsic_std_propagated``), ``sigma_px``, ``sigma_pos_m``, ``sigma_rot_rad``
        (estimated or given; None without pose noise), ``carrier_residuals`` ((N, 6)
        estimated carrier-pose errors, rad and m),
        ``still_rms_px`` (N,), ``rms_px``, ``param_names``, ``nfev``, ``vce_iterations``.

    Notes
    -----
    Without pose noise the covariance is ``s^2 (J^T J)^-1`` (``cvsflow.optimise.se3_cov.
    covariances``, linear loss). With pose noise the three groups (corners, carrier
    rotations, carrier translations) get their variances by Foerstner's variance-component
    estimation, ``sigma_g^2 <- sigma_g^2 v_g^T v_g / r_g`` with the redundancy
    ``r_g = m_g - tr(N^-1 J_g^T J_g)`` of the whitened problem, iterated with the fit until
    every factor is within 1e-2 of 1; the covariance is then ``N^-1`` (each group's
    ``v^T v / r`` being 1).
    """
    bad = [n for n in free_intrinsics if n not in INTRINSIC_NAMES]
    if bad:
        raise InputError(f"free intrinsics {bad}; expected names among {list(INTRINSIC_NAMES)}")
    uv = np.asarray(uv_px, float)
    T_W_X = np.asarray(T_W_X, float)
    p_B = np.asarray(p_B, float)
    intr0 = _intrinsics_vector(camera)
    free = tuple(free_intrinsics)
    sig = {"corners": 0.5, "pos": pose_sigma_m or 1e-3, "rot": pose_sigma_rad or np.radians(0.05)}
    fixed = {"corners": False, "pos": pose_sigma_m is not None, "rot": pose_sigma_rad is not None}
    T_H, T_G, intr = np.asarray(T0_H, float), np.asarray(T0_G, float), intr0
    delta = np.zeros(6 * len(uv))
    nfev, n_iter = 0, 0
    for it in range(1, (VCE_MAX_ITER if pose_noise else 1) + 1):
        n_iter = it
        model = _Model(T_W_X, mode, uv, p_B, T_H, T_G, intr, free, pose_noise,
                       (sig["corners"], sig["pos"], sig["rot"]))  # fmt: skip
        x0 = model.x0()
        if pose_noise:
            x0[model.k:] = delta
        sol = least_squares(model.residuals, x0, jac=model.jacobian, method="lm",
                            x_scale="jac", max_nfev=200)  # fmt: skip
        nfev += int(sol.nfev)
        T_H, T_G, intr = model.unpack(sol.x)
        delta = sol.x[model.k:]
        if not pose_noise:
            break
        J, r = model.jacobian(sol.x), model.residuals(sol.x)
        N_inv = _inverse(J.T @ J)
        worst = 0.0
        for g, rows in model.groups.items():
            red = rows.stop - rows.start - float(np.einsum("ij,ji->", N_inv, J[rows].T @ J[rows]))
            if fixed[g] or red <= 1e-9:
                continue
            factor = float(r[rows] @ r[rows]) / red
            sig[g] = max(sig[g] * np.sqrt(factor), SIGMA_FLOOR.get(g, 0.0))
            worst = max(worst, abs(factor - 1.0) if sig[g] > SIGMA_FLOOR.get(g, 0.0) else 0.0)
        if worst < VCE_TOL:
            break
    # Covariance about the solution itself: re-centred so the rotation errors are about the
    # axes of the solution's child frames.
    at = _Model(T_W_X, mode, uv, p_B, T_H, T_G, intr, free, pose_noise,
                (sig["corners"], sig["pos"], sig["rot"]))  # fmt: skip
    x_hat = at.x0()
    if pose_noise:
        x_hat[at.k:] = delta
    J = at.jacobian(x_hat)
    if pose_noise:
        cov = _inverse(J.T @ J)[: at.k, : at.k]
        sigma_px = sig["corners"]
    else:
        r = at.residuals(x_hat) * sig["corners"]  # px
        clusters = np.repeat(np.nonzero(at.seen)[0], 2)
        cov, _, _, sigma2, _, _ = covariances(J * sig["corners"], r, "linear", 1.0, clusters)
        sigma_px = float(np.sqrt(sigma2))
    # The fixed intrinsics are not exact: their calibration std (camera["std"], e.g. from
    # `cvsflow calibrate`) enters through the solution's sensitivity to them,
    # S = -(J^T J)^-1 J^T J_fixed (as cvsflow.optimise.se3_cov.fixed_sensitivity, linear loss).
    fixed_names = [nm for nm in INTRINSIC_NAMES if nm not in free]
    given = camera.get("std") if isinstance(camera.get("std"), dict) else {}
    sd_fixed = np.array([float(given.get(nm) or 0.0) for nm in fixed_names])
    propagated = [nm for nm, v in zip(fixed_names, sd_fixed, strict=True) if v > 0]
    if propagated:
        J_fixed = at.jacobian_fixed(x_hat)
        S = -(_inverse(J.T @ J) @ (J.T @ J_fixed))[: at.k]
        cov = cov + (S * sd_fixed**2) @ S.T
    rms = at.still_rms(x_hat)
    return {
        "intrinsic_std_propagated": propagated,
        "T_H": T_H, "T_G": T_G, "intrinsics": intr, "cov": cov,
        "sigma_px": float(sigma_px),
        "sigma_pos_m": float(sig["pos"]) if pose_noise else None,
        "sigma_rot_rad": float(sig["rot"]) if pose_noise else None,
        "carrier_residuals": delta.reshape(-1, 6) if pose_noise else np.zeros((len(uv), 6)),
        "still_rms_px": rms,
        "rms_px": float(np.sqrt(np.mean(rms**2))),
        "param_names": [*(f"H_{s}" for s in ("wx", "wy", "wz", "x", "y", "z")),
                        *(f"G_{s}" for s in ("wx", "wy", "wz", "x", "y", "z")),
                        *(n for n in INTRINSIC_NAMES if n in free_intrinsics)],
        "nfev": nfev, "vce_iterations": n_iter,
    }  # fmt: skip


def leave_one_out_rms(uv_px, p_B, T_W_X, camera, fit, mode, free_intrinsics=()):
    """Each still's reprojection RMS (px) under the fit of the other stills, poses as exact.

    A still with a grossly wrong carrier pose pulls an all-stills fit towards itself and
    spreads its error over the others; fitted without it, it stands out.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in the pose source's world W per still (T_W_Cm or T_W_Bm), m.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start and the fixed intrinsics.
    fit : dict
        The all-stills fit of :func:`refine_hand_eye` (``T_H``, ``T_G``, ``intrinsics``,
        ...); each refit starts from it.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).
    free_intrinsics : sequence of str, default ()
        Intrinsics refined with H and G (names in ``INTRINSIC_NAMES``).

    Returns
    -------
    ndarray, shape (N,)
        Reprojection RMS of still i under the fit without it (pose noise off: the carrier
        poses exact), px.
    """
    n = len(uv_px)
    out = np.empty(n)
    for i in range(n):
        keep = np.arange(n) != i
        f = refine_hand_eye(uv_px[keep], p_B, T_W_X[keep], camera, fit["T_H"], fit["T_G"], mode,
                            free_intrinsics, pose_noise=False)  # fmt: skip
        intr = f["intrinsics"]
        m = _Model(T_W_X[i : i + 1], mode, uv_px[i : i + 1], p_B, f["T_H"], f["T_G"], intr, ())
        out[i] = m.still_rms(m.x0())[0]
    return out


def _inverse(N):
    """Inverse of a normal matrix: LU (the priors make it positive definite), SVD if singular.

    numpy's SVD is ~1000x slower than LU on these badly scaled matrices.
    """
    try:
        return np.linalg.inv(N)
    except np.linalg.LinAlgError:
        return np.linalg.pinv(N)


def _deviation(T_ref, T):
    """[w (rad, about the child axes of T_ref), t (m, in the parent)] of T against T_ref."""
    return np.concatenate([tf.rvec_from_R(T_ref[:3, :3].T @ T[:3, :3]), T[:3, 3] - T_ref[:3, 3]])


def jackknife_std(uv_px, p_B, T_W_X, camera, fit, mode, free_intrinsics, **kw):
    """Delete-one-still jackknife standard errors of a refined fit, same order as ``fit['cov']``.

    ``sqrt((n-1)/n sum_i (theta_(i) - mean theta_(.))^2)`` (Efron and Tibshirani 1993, eq.
    11.5), each refit started at the full fit; None with fewer than 5 stills.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Corners of each still in board order, px.
    p_B : ndarray, shape (P, 3)
        The corners in B, m.
    T_W_X : ndarray, shape (N, 4, 4)
        Carrier pose in the pose source's world W per still (T_W_Cm or T_W_Bm), m.
    camera : dict
        ``K`` (3x3, px), ``dist`` (5 values): the start and the fixed intrinsics.
    fit : dict
        The all-stills fit of :func:`refine_hand_eye` (``T_H``, ``T_G``, ``intrinsics``,
        ...); each refit starts from it.
    mode : {"eye_in_hand", "eye_to_hand"}
        Which body the carrier X is: the camera's (Cm) or the board's (Bm).
    free_intrinsics : sequence of str
        Intrinsics refined with H and G (names in ``INTRINSIC_NAMES``).
    **kw
        Passed to :func:`refine_hand_eye` (``pose_noise``, ``pose_sigma_m``, ...).

    Returns
    -------
    ndarray, shape (12 + n_free,) or None
        Standard errors of H's rotation (rad, about its child axes) and translation (m), then
        G's likewise, then the free intrinsics (px, or unitless for distortion); None with
        fewer than ``MIN_STILLS + 2`` stills.
    """
    n = len(uv_px)
    if n < MIN_STILLS + 2:
        return None
    devs = []
    for i in range(n):
        keep = np.arange(n) != i
        f = refine_hand_eye(uv_px[keep], p_B, T_W_X[keep], camera, fit["T_H"], fit["T_G"], mode,
                            free_intrinsics, **kw)  # fmt: skip
        d_intr = (f["intrinsics"] - fit["intrinsics"])[
            [k for k, nm in enumerate(INTRINSIC_NAMES) if nm in free_intrinsics]
        ]
        devs.append(np.concatenate([_deviation(fit["T_H"], f["T_H"]),
                                    _deviation(fit["T_G"], f["T_G"]), d_intr]))  # fmt: skip
    devs = np.asarray(devs)
    return np.sqrt((n - 1) / n * np.sum((devs - devs.mean(axis=0)) ** 2, axis=0))
