"""The seed optimiser's PnP: board poses of many frames at many focal lengths at once.

Every candidate focal length of the seed search (:mod:`cvsflow.optimise.seed`) re-runs PnP
on all frames, so PnP here is a vectorised Levenberg-Marquardt over stacks of (candidate,
frame) rows minimising the pixel reprojection error with OpenCV's distortion model (the
same cost as ``cv2.solvePnP(..., SOLVEPNP_ITERATIVE)``), warm-started from the poses at the
current focal lengths moved by their first-order sensitivity to (fx, fy)
(:func:`focal_sensitivity`, implicit-function theorem). Undistorting the corners once is not
exact: the normalised coordinates ``((u - cx) / fx, (v - cy) / fy)`` scale with the candidate
f *before* the nonlinear undistortion, so the undistorted points change with every candidate;
the forward model in pixels keeps it exact.

Stacks are cut into cache-sized chunks (:data:`ROWS_PER_CHUNK`) that ``n_workers`` threads
share. Every row's arithmetic is independent of the others, so neither the stacking, the
chunking nor the threads change a single bit of the result (bench/bench_seed.py compares the
output files' sha256 with an earlier revision).

The projection and its Jacobian are :func:`cvsflow.geometry.camera.project_poses` and
:func:`~cvsflow.geometry.camera.pose_jacobian` (per-row focal lengths, buffered arithmetic).
"""

from __future__ import annotations

import numpy as np

from cvsflow.exceptions import OptimiseError
from cvsflow.geometry import R_from_rvec, pose_jacobian, project_poses, rvec_from_R

#: Rows (candidate x frame) per stack of :func:`solve_rows`: bounds the memory of one
#: stack (about 10 kB per row for a 20-corner board) while keeping numpy's per-call
#: overhead small.
ROWS_PER_CHUNK = 1024


def _project_with_jacobian(R_C_B, t_C_B, X_B, fx, fy, cx, cy, dist, want_jac=True):
    """Distorted pixel projections (N, P, 2), xd, yd and d(u, v)/d(omega, t) (N, P, 2, 6)."""
    uv, xd, yd, parts = project_poses(R_C_B, t_C_B, X_B, fx, fy, cx, cy, dist)
    return uv, xd, yd, (pose_jacobian(parts, fx, fy, dist) if want_jac else None)


def dist5(dist):
    """Distortion as (k1, k2, p1, p2, k3); longer models must have zero extra terms.

    Parameters
    ----------
    dist : array_like
        OpenCV distortion coefficients [k1, k2, p1, p2(, k3, ...)].

    Returns
    -------
    ndarray, shape (5,)
        [k1, k2, p1, p2, k3], missing terms zero.

    Raises
    ------
    OptimiseError
        More than 5 coefficients with a nonzero rational or prism term.
    """
    d = np.zeros(5)
    dist = np.ravel(np.asarray(dist, dtype=float))
    if dist.size > 5 and np.any(dist[5:] != 0):
        raise OptimiseError(
            f"camera dist: {dist.size} coefficients with nonzero rational/prism terms; the seed "
            "optimiser supports [k1, k2, p1, p2, k3]"
        )
    d[: min(5, dist.size)] = dist[:5]
    return d


def solve_pnp_batch(
    uv_px, X_B, fx_px, fy_px, cx_px, cy_px, dist, rvec_C_B, tvec_C_B, max_iter=10, tol=1e-10
):
    """Least-squares PnP of many frames at once (vectorised Gauss-Newton).

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed distorted corner positions, pixels.
    X_B : ndarray, shape (P, 3)
        Corner positions in the board frame B, metres.
    fx_px, fy_px, cx_px, cy_px : float
        Intrinsics, pixels.
    dist : array_like, shape (4,) or (5,)
        OpenCV distortion [k1, k2, p1, p2(, k3)].
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        Starting poses of B in C (rad, metres), e.g. the solution at nearby focal lengths.
    max_iter : int
        Gauss-Newton iterations at most.
    tol : float
        Stop when every frame's update is below this (rad and metres).

    Returns
    -------
    rvec_C_B, tvec_C_B : ndarray, shape (N, 3)
        Poses minimising the summed squared pixel reprojection error (the cost of
        ``cv2.solvePnP`` with ``SOLVEPNP_ITERATIVE``), rad and metres.
    n_iter : int
        Iterations run.
    """
    R, t, n_iter = _solve_R_t(
        uv_px, X_B, fx_px, fy_px, cx_px, cy_px, dist5(dist),
        R_from_rvec(rvec_C_B), np.array(tvec_C_B, dtype=float), max_iter, tol,
    )
    return rvec_from_R(R), t, n_iter


def _solve_R_t(uv_px, X_B, fx, fy, cx, cy, dist5, R, t, max_iter, tol):
    """Levenberg-Marquardt on (R, t) stacks, each frame damped and stopped on its own.

    ``fx``, ``fy`` are scalars or one value per row (N,), so that many candidate focal
    lengths are solved in one stack (:func:`solve_rows`). Returns R (N, 3, 3), t (N, 3) and
    the iterations run. A row stops when its update is below ``tol`` (rad, metres); only the
    still active rows are recomputed.

    Every row's arithmetic is independent of the other rows, so a row's result does not
    depend on which rows share the stack. The residual at the trial pose is kept and reused
    as the next iteration's (the same numbers a fresh projection at that pose would give), so
    each iteration projects once; its Jacobian, most of a projection's work, is formed only
    for the rows that go on from an accepted step (a row that stops or runs out of
    iterations never uses it; a rejected row keeps its previous one).
    """
    R = np.array(R, dtype=float)
    t = np.array(t, dtype=float)
    n = uv_px.shape[0]
    # per-row focal lengths, (N, 1) to broadcast over the corners
    fxa = np.broadcast_to(np.asarray(fx, dtype=float), (n,))[:, None]
    fya = np.broadcast_to(np.asarray(fy, dtype=float), (n,))[:, None]
    # the active rows' state, compacted when rows stop
    rows = np.arange(n)
    Ra, ta, obs = R.copy(), t.copy(), np.asarray(uv_px, dtype=float)
    uva, _, _, Ja = _project_with_jacobian(Ra, ta, X_B, fxa, fya, cx, cy, dist5)
    resa = obs - uva
    costa = np.sum(resa ** 2, axis=(1, 2))
    lama = np.full(n, 1e-4)
    eye6 = np.eye(6)
    n_iter = 0
    for n_iter in range(1, max_iter + 1):  # noqa: B007
        m = rows.size
        r = resa.reshape(m, -1, 1)
        Jf = Ja.reshape(m, -1, 6)
        JfT = Jf.transpose(0, 2, 1)
        JtJ = JfT @ Jf
        Jtr = JfT @ r
        damp = lama[:, None, None] * (JtJ * eye6)  # Marquardt's diagonal scaling
        delta = np.linalg.solve(JtJ + damp, Jtr)[..., 0]
        R_new = R_from_rvec(delta[:, :3]) @ Ra  # exp([delta_w]x) R
        t_new = ta + delta[:, 3:]
        uv_new, _, _, parts = project_poses(R_new, t_new, X_B, fxa, fya, cx, cy, dist5)
        res_new = obs - uv_new
        cost_new = np.sum(res_new ** 2, axis=(1, 2))
        accept = cost_new <= costa
        reject = ~accept
        if reject.any():  # rejected rows keep their pose and its linearisation
            R_new[reject], t_new[reject], cost_new[reject] = Ra[reject], ta[reject], costa[reject]
            res_new[reject] = resa[reject]
        lama = np.where(accept, np.maximum(lama * 0.1, 1e-9), lama * 10.0)
        step = np.max(np.abs(delta), axis=1)
        done = (accept & (step < tol)) | (lama > 1e6)
        keep = ~done
        if n_iter < max_iter and keep.any():  # the next iteration's Jacobian, kept rows only
            if keep.all():
                J_new = pose_jacobian(parts, fxa, fya, dist5)
            else:
                J_new = pose_jacobian([v[keep] for v in parts], fxa[keep], fya[keep], dist5)
            # A rejected row keeps the Jacobian of its unchanged pose. Rejections are rare
            # (about 1 in 100 rows), so its wasted row of the new Jacobian costs less than
            # cutting the kept Jacobian and the accepted rows' intermediates apart.
            stale = reject[keep]
            if stale.any():
                J_new[stale] = Ja[keep & reject]
            Ja = J_new
        Ra, ta, costa, resa = R_new, t_new, cost_new, res_new
        if done.any():
            R[rows[done]], t[rows[done]] = Ra[done], ta[done]
            rows, Ra, ta, costa, resa = rows[keep], Ra[keep], ta[keep], costa[keep], resa[keep]
            obs, fxa, fya, lama = obs[keep], fxa[keep], fya[keep], lama[keep]
            if rows.size == 0:
                break
    R[rows], t[rows] = Ra, ta  # rows still active after max_iter keep their last accepted pose
    return R, t, n_iter


def solve_rows(uv_px, frame_of_row, X_B, fx_rows, fy_rows, cx, cy, dist5, R, t, max_iter, tol,
               pool=None, n_workers=1, rows_per_chunk=None):
    """PnP of many (candidate, frame) rows, in chunks, on a thread pool if given.

    Row i solves frame ``frame_of_row[i]`` at focal lengths ``fx_rows[i], fy_rows[i]`` from
    the pose ``R[i], t[i]``. Rows are independent (see ``_solve_R_t``), so neither the
    chunking nor the threads change a result.

    Parameters
    ----------
    uv_px : ndarray, shape (N_frames, P, 2)
        Observed distorted corners of every frame, px.
    frame_of_row : ndarray of int, shape (M,)
        Index into ``uv_px`` of each row.
    X_B : ndarray, shape (P, 3)
        Corners in the board frame, metres.
    fx_rows, fy_rows : ndarray, shape (M,)
        Focal lengths of each row, px.
    cx, cy : float
        Principal point, px.
    dist5 : ndarray, shape (5,)
        [k1, k2, p1, p2, k3] (:func:`dist5`).
    R, t : ndarray, shape (M, 3, 3) and (M, 3)
        Starting poses T_C_B, metres.
    max_iter, tol : int, float
        Iterations at most; a row stops when its update is below ``tol`` (rad, metres).
    pool : concurrent.futures.ThreadPoolExecutor, optional
        Threads sharing the chunks.
    n_workers : int
        At least this many chunks when ``pool`` is given.
    rows_per_chunk : int, optional
        Rows per chunk at most (default :data:`ROWS_PER_CHUNK`).

    Returns
    -------
    R, t : ndarray, shape (M, 3, 3) and (M, 3)
        Poses T_C_B minimising each row's pixel reprojection error, metres.
    """
    n = frame_of_row.size
    rows_per_chunk = ROWS_PER_CHUNK if rows_per_chunk is None else rows_per_chunk
    n_chunks = max(int(n_workers) if pool is not None else 1, -(-n // int(rows_per_chunk)))
    n_chunks = max(1, min(n_chunks, n))
    bounds = np.linspace(0, n, n_chunks + 1).astype(int)

    def work(i):
        s = slice(bounds[i], bounds[i + 1])
        return _solve_R_t(uv_px[frame_of_row[s]], X_B, fx_rows[s], fy_rows[s], cx, cy, dist5,
                          R[s], t[s], max_iter, tol)[:2]

    if pool is not None and n_chunks > 1:
        parts = list(pool.map(work, range(n_chunks)))
    else:
        parts = [work(i) for i in range(n_chunks)]
    return np.concatenate([q[0] for q in parts]), np.concatenate([q[1] for q in parts])


def focal_sensitivity(uv_px, X_B, fx, fy, cx, cy, dist5, R, t):
    """d(omega, t)/d(fx, fy) of PnP optima, by the implicit-function theorem.

    Parameters
    ----------
    uv_px : ndarray, shape (N, P, 2)
        Observed corners, px (only their count is used: at an optimum the sensitivity
        depends on the model alone, Gauss-Newton's approximation).
    X_B : ndarray, shape (P, 3)
        Corners in the board frame, metres.
    fx, fy, cx, cy : float
        Intrinsics at the optima, px.
    dist5 : ndarray, shape (5,)
        [k1, k2, p1, p2, k3].
    R, t : ndarray, shape (N, 3, 3) and (N, 3)
        The optimal poses T_C_B, metres.

    Returns
    -------
    ndarray, shape (N, 6, 2)
        Derivative of (left rotation increment omega, rad; t, metres) per px of (fx, fy).
    """
    _, xd, yd, J = _project_with_jacobian(R, t, X_B, fx, fy, cx, cy, dist5)
    n = uv_px.shape[0]
    Jf = J.reshape(n, -1, 6)
    dproj_df = np.zeros(J.shape[:2] + (2, 2))
    dproj_df[..., 0, 0] = xd  # du/dfx
    dproj_df[..., 1, 1] = yd  # dv/dfy
    dproj_df = dproj_df.reshape(n, -1, 2)
    JtJ = np.einsum("nki,nkj->nij", Jf, Jf)
    Jtd = np.einsum("nki,nkj->nij", Jf, dproj_df)
    return -np.linalg.solve(JtJ, Jtd)
