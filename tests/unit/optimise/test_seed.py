"""Tests of cvsflow.optimise.seed: the chapter's focal-length and offset optimiser."""

from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np
import pandas as pd
import pytest

from cvsflow.board.model import board_object_points
from cvsflow.exceptions import OptimiseError
from cvsflow.geometry.camera import pose_jacobian, project_poses
from cvsflow.geometry.transforms import R_from_rvec, T_from_pose6, rvec_tvec_from_T
from cvsflow.metrics import ERROR_DIMS
from cvsflow.optimise.seed import (
    compute_eps,
    compute_p_bar,
    normalised_error_norm,
    objective_value,
    optimise_seed,
)
from cvsflow.optimise.seed_pnp import (
    _project_with_jacobian,
    _solve_R_t,
    dist5,
    solve_pnp_batch,
    solve_rows,
)

BOARD = {"squares_x": 6, "squares_y": 5, "square_m": 0.09}
DIST = np.array([-0.12, 0.09, 0.0009, -0.0007, -0.02])
OFFSET = np.array([0.05, -0.03, 0.10, 0.02, -0.01, 3.0])  # P_bar truth (m, rad); yaw near pi


def _session(n_frames, fx=700.0, fy=700.0, noise_px=0.2, seed=0):
    """Synthetic pairs and corners: smooth board trajectory at 1-4 m, known K, P* = truth - OFFSET."""
    rng = np.random.default_rng(seed)
    X_B = board_object_points(BOARD)
    K = np.array([[fx, 0.0, 320.0], [0.0, fy, 240.0], [0.0, 0.0, 1.0]])
    t_s = np.arange(n_frames) / 30.0
    phase = rng.uniform(0, 2 * np.pi, 6)
    freq = rng.uniform(0.05, 0.25, 6)
    s = np.sin(2 * np.pi * freq * t_s[:, None] + phase)
    z = 2.5 + 1.4 * s[:, 2]
    pose = np.stack(
        [0.2 * z * s[:, 0] - 0.18, 0.15 * z * s[:, 1] - 0.135, z,
         0.5 * s[:, 3], 0.5 * s[:, 4], 0.3 * s[:, 5]], axis=1)
    rvec, tvec = rvec_tvec_from_T(T_from_pose6(pose))
    uv = np.stack([cv2.projectPoints(X_B, rvec[i], tvec[i], K, DIST)[0][:, 0]
                   for i in range(n_frames)])
    uv = uv + rng.normal(0.0, noise_px, uv.shape)
    frames = np.arange(n_frames) + 100
    n_c = X_B.shape[0]
    corners = pd.DataFrame({
        "frame": np.repeat(frames, n_c), "t_s": np.repeat(t_s, n_c), "found": True,
        "corner": np.tile(np.arange(n_c), n_frames),
        "u_px": uv[..., 0].ravel(), "v_px": uv[..., 1].ravel()})
    pairs = pd.DataFrame({"frame": frames, "t_s": t_s})
    P_star = pose - OFFSET
    P_star[:, 3:] = np.angle(np.exp(1j * P_star[:, 3:]))
    for i, d in enumerate(ERROR_DIMS):
        pairs[f"cvs_{d}"] = pose[:, i]
        pairs[f"vic_{d}"] = P_star[:, i]
    for i in range(3):
        pairs[f"cvs_rvec_{i}"] = rvec[:, i]
    return pairs, corners, K, pose, uv, rvec, tvec


def test_board_object_points_layout():
    """Corner k lies at ((k % nx) s, (k // nx) s, 0) with nx = squares_x - 1."""
    X = board_object_points(BOARD)
    assert X.shape == (20, 3)
    np.testing.assert_allclose(X[6], [0.09, 0.09, 0.0])
    np.testing.assert_allclose(X[19], [0.36, 0.27, 0.0])


def test_solve_pnp_batch_matches_opencv():
    """Batched LM PnP equals cv2.solvePnP(ITERATIVE) at a different f to 1e-5 m / 1e-5 rad."""
    pairs, corners, K, pose, uv, rvec, tvec = _session(60, seed=3)
    X_B = board_object_points(BOARD)
    K2 = K.copy()
    K2[0, 0], K2[1, 1] = 690.0, 712.0
    r_b, t_b, _ = solve_pnp_batch(uv, X_B, 690.0, 712.0, 320.0, 240.0, DIST, rvec, tvec,
                                  max_iter=50, tol=1e-12)
    for i in range(len(uv)):
        _, r_cv, t_cv = cv2.solvePnP(X_B, uv[i], K2, DIST, rvec=rvec[i].copy(),
                                     tvec=tvec[i].copy(), useExtrinsicGuess=True,
                                     flags=cv2.SOLVEPNP_ITERATIVE)
        np.testing.assert_allclose(t_b[i], t_cv.ravel(), atol=1e-5)
        np.testing.assert_allclose(r_b[i], r_cv.ravel(), atol=1e-5)


def test_batched_candidates_equal_one_solve_per_candidate_bit_for_bit():
    """Stacking candidates, cutting the stack into chunks and threads change no bit of a pose.

    optimise_seed solves all candidates of a grid level in one stack (solve_rows); its
    outputs are only reproducible if a row's result does not depend on its neighbours.
    """
    _, _, _, _, uv, rvec, tvec = _session(40, seed=5)
    X_B = board_object_points(BOARD)
    cands = np.array([[690.0, 712.0], [700.0, 700.0], [640.0, 760.0]])
    n = len(uv)
    R0, d5 = R_from_rvec(rvec), dist5(DIST)
    one = [_solve_R_t(uv, X_B, fx, fy, 320.0, 240.0, d5, R0, tvec, 10, 1e-6)[:2]
           for fx, fy in cands]
    rows = np.tile(np.arange(n), len(cands))
    with ThreadPoolExecutor(2) as pool:
        R, t = solve_rows(uv, rows, X_B, np.repeat(cands[:, 0], n), np.repeat(cands[:, 1], n),
                          320.0, 240.0, d5, np.tile(R0, (3, 1, 1)), np.tile(tvec, (3, 1)), 10,
                          1e-6, pool=pool, n_workers=2, rows_per_chunk=7)
    for k, (R_k, t_k) in enumerate(one):
        assert R[k * n:(k + 1) * n].tobytes() == R_k.tobytes()
        assert t[k * n:(k + 1) * n].tobytes() == t_k.tobytes()
    # and the candidates did move the poses (the comparison is not between start values)
    assert not np.array_equal(one[0][1], one[2][1])


def _textbook_projection(R, t, X_B, fx, fy, cx, cy, dist):
    """The projection and Jacobian written as plain expressions (one temporary per operation)."""
    q = R @ X_B.T
    qx, qy, qz = q[:, 0], q[:, 1], q[:, 2]
    inv_z = 1.0 / (qz + t[:, 2:3])
    x = (qx + t[:, 0:1]) * inv_z
    y = (qy + t[:, 1:2]) * inv_z
    k1, k2, p1, p2, k3 = dist
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    two_p1_x, two_p2_x = 2.0 * p1 * x, 2.0 * p2 * x
    xd = x * radial + two_p1_x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + two_p2_x * y
    uv = np.stack([fx * xd + cx, fy * yd + cy], axis=-1)
    dr = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)
    dxd_dx = radial + 2.0 * x * x * dr + 2.0 * p1 * y + 6.0 * p2 * x
    dxd_dy = 2.0 * x * y * dr + two_p1_x + 2.0 * p2 * y
    dyd_dy = radial + 2.0 * y * y * dr + 6.0 * p1 * y + two_p2_x
    J = np.empty(x.shape + (2, 6))
    for row, (du_dx, du_dy) in enumerate(((fx * dxd_dx, fx * dxd_dy), (fy * dxd_dy, fy * dyd_dy))):
        a0, a1, a2 = du_dx * inv_z, du_dy * inv_z, -(du_dx * x + du_dy * y) * inv_z
        J[..., row, :] = np.stack([qy * a2 - qz * a1, qz * a0 - qx * a2, qx * a1 - qy * a0,
                                   a0, a1, a2], axis=-1)
    return uv, xd, yd, J


def test_projection_and_jacobian_equal_the_textbook_expressions_bit_for_bit():
    """The buffered projection and Jacobian (out= arithmetic) equal the plain expressions in
    every bit, against finite differences too; the Jacobian of a row subset is that subset."""
    _, _, _, _, uv_obs, rvec, tvec = _session(30, seed=7)
    X_B = board_object_points(BOARD)
    rng = np.random.default_rng(8)
    R = R_from_rvec(rvec)
    fx, fy = rng.uniform(600, 800, (30, 1)), rng.uniform(600, 800, (30, 1))
    d5 = dist5(DIST)
    got = _project_with_jacobian(R, tvec, X_B, fx, fy, 320.0, 240.0, d5)
    want = _textbook_projection(R, tvec, X_B, fx, fy, 320.0, 240.0, d5)
    for g, w in zip(got, want, strict=True):
        assert g.shape == w.shape and g.tobytes() == w.tobytes()
    at_truth = project_poses(R, tvec, X_B, 700.0, 700.0, 320.0, 240.0, d5)[0]
    np.testing.assert_allclose(at_truth, uv_obs, atol=1.5)  # 0.2 px noise: it projects these frames
    sub = rng.random(30) < 0.5
    _, _, _, parts = project_poses(R, tvec, X_B, fx, fy, 320.0, 240.0, d5)
    J_sub = pose_jacobian([v[sub] for v in parts], fx[sub], fy[sub], d5)
    assert J_sub.tobytes() == got[3][sub].tobytes()
    # d(u, v)/dt by central differences: the Jacobian is a derivative, not only self-consistent
    h = 1e-7
    for k in range(3):
        dt = np.zeros(3)
        dt[k] = h
        up = project_poses(R, tvec + dt, X_B, fx, fy, 320.0, 240.0, d5)[0]
        dn = project_poses(R, tvec - dt, X_B, fx, fy, 320.0, 240.0, d5)[0]
        np.testing.assert_allclose(got[3][..., 3 + k], (up - dn) / (2 * h), rtol=1e-5, atol=1e-3)


def test_p_bar_and_eps_by_hand():
    """Eq. 1.10 is the mean difference (circular for angles); eq. 1.11 gives zero-mean eps."""
    rng = np.random.default_rng(1)
    F = rng.normal(size=(50, 6))
    P_star = F - np.array([0.1, 0.2, 0.3, 0.0, 0.1, np.pi - 0.01]) + rng.normal(0, 0.01, (50, 6))
    P_bar = compute_p_bar(F, P_star)
    d = F - P_star
    np.testing.assert_allclose(P_bar[:3], d[:, :3].mean(axis=0), atol=1e-12)
    ang = np.angle(np.exp(1j * d[:, 3:]).mean(axis=0))
    np.testing.assert_allclose(P_bar[3:], ang, atol=1e-12)
    assert abs(P_bar[5]) > 3.0  # the offset near pi is not averaged to ~0
    eps = compute_eps(F, P_star, P_bar)
    np.testing.assert_allclose(eps[:, :3].mean(axis=0), 0.0, atol=1e-12)
    assert np.all(np.abs(eps[:, 3:]) < 0.1)  # wrapped, not ~2 pi


def test_objectives_by_hand():
    """Objective values equal their numpy definitions; an unknown name is an OptimiseError."""
    e = np.random.default_rng(2).normal(size=(30, 3))
    assert objective_value(e, "summed") == pytest.approx(np.linalg.norm(e.sum(axis=0)))
    assert objective_value(e, "sum_abs") == pytest.approx(np.linalg.norm(np.abs(e).sum(axis=0)))
    assert objective_value(e, "sum_squares") == pytest.approx(np.sum(e**2))
    assert normalised_error_norm(e) == pytest.approx(np.sqrt(np.mean(np.sum(e**2, axis=1))))
    with pytest.raises(OptimiseError, match="objective"):
        objective_value(e, "frobenius")


def test_sum_squares_moves_focal_lengths_to_truth():
    """From f = (665, 730) px with truth (700, 700), sum_squares ends within 8 px of truth and
    recovers P_bar's translation to 2 cm; the normalised error norm drops at least fivefold."""
    pairs, corners, K, *_ = _session(240, seed=4)
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=12, f_init_px=(665, 730),
                        objective="sum_squares", grid_half_width_px=32, grid_points=3,
                        grid_levels=5)
    fx, fy = res.result["fx_px"], res.result["fy_px"]
    assert abs(fx - 700) < 8 and abs(fy - 700) < 8
    np.testing.assert_allclose(res.result["P_bar"][:3], OFFSET[:3], atol=0.02)
    assert res.result["norm_normalised_final_m"] < res.result["norm_normalised_init_m"] / 5
    it = res.iterations
    assert len(it) == 13 and it["iteration"].tolist() == list(range(13))
    # block-coordinate descent: the objective never increases from one iteration to the next
    assert np.all(np.diff(it["objective"]) <= 1e-9)


def test_sum_abs_moves_towards_truth():
    """The sum_abs variant also moves (fx, fy) towards the truth (distance at least halved)."""
    pairs, corners, K, *_ = _session(150, seed=5)
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=5, f_init_px=(670, 725),
                        objective="sum_abs", grid_points=3, grid_levels=5)
    d0 = np.hypot(670 - 700, 725 - 700)
    d1 = np.hypot(res.result["fx_px"] - 700, res.result["fy_px"] - 700)
    assert d1 < d0 / 2


def test_literal_summed_objective_never_moves():
    """Eq. 1.12 literally: sum_i eps_i = 0 at the current f, so fx, fy stay at their start."""
    pairs, corners, K, *_ = _session(80, seed=6)
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=3, f_init_px=(660, 740),
                        objective="summed", grid_points=3, grid_levels=3)
    assert res.result["fx_px"] == 660 and res.result["fy_px"] == 740
    np.testing.assert_allclose(res.iterations["objective"], 0.0, atol=1e-9)
    np.testing.assert_allclose(res.iterations["objective_grid_min"].iloc[:-1], 0.0, atol=1e-9)


def test_tables_and_result_schema():
    """iterations, errors and result carry the documented columns; eps columns match by hand."""
    pairs, corners, K, *_ = _session(40, seed=7)
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=1, grid_points=3,
                        grid_levels=2)
    it, err = res.iterations, res.errors
    for d in ERROR_DIMS:
        for pre in ("P_bar_", "eps_mean_", "eps_std_", "eps_rmse_"):
            assert pre + d in it.columns
        for pre in ("vic_", "cvs_", "cvs_orig_", "eps_", "eps_orig_"):
            assert pre + d in err.columns
    for col in ("iteration", "fx_px", "fy_px", "objective", "norm_normalised"):
        assert col in it.columns
    F = err[[f"cvs_{d}" for d in ERROR_DIMS]].to_numpy()
    P = err[[f"vic_{d}" for d in ERROR_DIMS]].to_numpy()
    P_bar = np.array(res.result["P_bar"])
    np.testing.assert_allclose(err[[f"eps_{d}" for d in ERROR_DIMS]].to_numpy(),
                               compute_eps(F, P, P_bar), atol=1e-12)
    eps = err[[f"eps_{d}" for d in ERROR_DIMS]].to_numpy()
    np.testing.assert_allclose(it[[f"eps_rmse_{d}" for d in ERROR_DIMS]].iloc[-1],
                               np.sqrt(np.mean(eps**2, axis=0)), rtol=1e-12)
    assert res.result["n_pairs"] == 40 and res.result["iterations"] == 1
    assert set(res.result) >= {"fx_px", "fy_px", "P_bar", "objective", "timings_s",
                               "norm_normalised_init_m", "norm_normalised_final_m"}


def test_threads_give_identical_result():
    """n_workers=2 gives bit-identical focal lengths and objective to n_workers=1."""
    pairs, corners, K, *_ = _session(60, seed=8)
    kw = dict(k_iterations=2, f_init_px=(680, 720), grid_points=3, grid_levels=3)
    a = optimise_seed(pairs, corners, K, DIST, BOARD, n_workers=1, **kw)
    b = optimise_seed(pairs, corners, K, DIST, BOARD, n_workers=2, **kw)
    assert (a.result["fx_px"], a.result["fy_px"]) == (b.result["fx_px"], b.result["fy_px"])
    assert a.result["objective"] == b.result["objective"]


def test_too_few_pairs_raises():
    """Fewer than 10 pairs is an OptimiseError naming pairs.parquet."""
    pairs, corners, K, *_ = _session(12, seed=9)
    with pytest.raises(OptimiseError, match="pairs.parquet: 5 pairs"):
        optimise_seed(pairs.iloc[:5], corners, K, DIST, BOARD, k_iterations=1)


def test_missing_corners_names_frame():
    """A pair frame with no corner at all raises OptimiseError naming that frame; one that lacks
    a single corner (partly hidden board) is left out of the fit."""
    pairs, corners, K, *_ = _session(12, seed=10)
    with pytest.raises(OptimiseError, match="frame 105"):
        optimise_seed(pairs, corners[corners["frame"] != 105], K, DIST, BOARD, k_iterations=1)
    partial = corners[~((corners["frame"] == 105) & (corners["corner"] == 3))]
    run = optimise_seed(pairs, partial, K, DIST, BOARD, k_iterations=1)
    assert run.result["n_pairs"] == len(pairs) - 1
    assert 105 not in set(run.errors["frame"])


def test_missing_columns_and_bad_grid_raise():
    """Missing vic_* columns and an even grid_points are OptimiseErrors saying what is wrong."""
    pairs, corners, K, *_ = _session(12, seed=11)
    with pytest.raises(OptimiseError, match="vic_yaw_rad"):
        optimise_seed(pairs.drop(columns="vic_yaw_rad"), corners, K, DIST, BOARD)
    with pytest.raises(OptimiseError, match="grid_points"):
        optimise_seed(pairs, corners, K, DIST, BOARD, grid_points=4)


def test_seed_leaves_out_pairs_with_part_of_the_board():
    """Pairs whose frame holds only some corners (hand or image border) are left out of the
    chapter's method, which re-estimates each pose from the whole board; a pairs frame with no
    corner at all is still an error naming it."""
    from cvsflow.optimise.seed_search import corner_array

    corners = pd.DataFrame(
        {"frame": [0] * 4 + [1] * 3, "found": True, "corner": [0, 1, 2, 3, 0, 1, 3],
         "u_px": np.arange(7.0), "v_px": np.arange(7.0)}
    )
    uv = corner_array(corners, [0, 1], 4, allow_partial=True)
    assert np.isfinite(uv[0]).all() and np.isnan(uv[1, 2]).all() and np.isfinite(uv[1, 3]).all()
    with pytest.raises(OptimiseError, match="frame 1 .*no complete set of 4"):
        corner_array(corners, [0, 1], 4)
    with pytest.raises(OptimiseError, match="frame 2 .*no found corner"):
        corner_array(corners, [0, 1, 2], 4, allow_partial=True)


def test_seed_without_whole_boards_says_to_run_se3_alone():
    """Every frame with a corner hidden (a hand over the board throughout, as on the realistic
    640x480 render): the error names the count and the way out."""
    pairs, corners, K, *_ = _session(12, seed=11)
    partial = corners[corners["corner"] != 0]
    with pytest.raises(OptimiseError, match=r"0 pairs with the whole board .*methods: \[se3\] "
                       r"in its sessions\.<name> block"):
        optimise_seed(pairs, partial, K, DIST, BOARD)


def test_divergence_flags_by_hand():
    """Bound, focal ratio and translation-std criteria each give their own reason."""
    from cvsflow.optimise.seed import seed_divergence

    ok = seed_divergence((705, 698), (700, 700), (100, 5000), 16.0, (0.01, 0.02, 0.03))
    assert ok is None
    at_bound = seed_divergence((285.7, 4985.8), (701.7, 697.8), (100, 5000), 16.0, (0.1, 0.1, 0.1))
    assert "fy = 4985.8 px within a grid step" in at_bound and "fx" not in at_bound.split(";")[0]
    assert "7.15 x the calibrated" in at_bound
    small = seed_divergence((150, 700), (700, 700), (100, 5000), 16.0, (0.1, 0.1, 0.1))
    assert "0.21 x the calibrated" in small and "bound" not in small
    wide = seed_divergence((700, 700), (700, 700), (100, 5000), 16.0, (0.1, 1.8, 0.1))
    assert "exceeds 1 m" in wide


def test_run_stopped_by_the_grid_bound_is_marked_diverged():
    """Truth f = 700 px, grid capped at 680 px: f ends on the bound and the result says so;
    an unconstrained run on the same data is not flagged."""
    pairs, corners, K, *_ = _session(120, seed=4)
    kw = dict(k_iterations=4, f_init_px=(665, 670), grid_half_width_px=32, grid_points=3, grid_levels=4)
    capped = optimise_seed(pairs, corners, K, DIST, BOARD, f_bounds_px=(100.0, 680.0), **kw).result
    assert capped["diverged"] is True
    assert "bound" in capped["diverged_reason"]
    free = optimise_seed(pairs, corners, K, DIST, BOARD, **kw).result
    assert free["diverged"] is False and free["diverged_reason"] is None


def test_convergence_figure_marks_the_grid_bound_it_reached():
    """The seed convergence figure draws the bound f reached, and not the one far away."""
    from cvsflow.evaluate.analyse import convergence
    from cvsflow.plots.results import plot_convergence

    pairs, corners, K, *_ = _session(60, seed=4)
    res = optimise_seed(pairs, corners, K, DIST, BOARD, k_iterations=3, f_init_px=(665, 670),
                        grid_points=3, grid_levels=3, f_bounds_px=(100.0, 680.0))
    fig = plot_convergence(convergence(res.iterations), res.result["f_bounds_px"])
    labels = [t.get_text() for t in fig.axes[6].get_legend().get_texts()]
    assert "grid bound 680 px" in labels and "grid bound 100 px" not in labels


def _plain_lm(uv, X_B, fx, fy, cx, cy, d5, R, t, max_iter, tol):
    """The LM of _solve_R_t written plainly: one row at a time, a fresh projection and Jacobian
    at the current pose every iteration, nothing reused, nothing compacted."""
    R, t = R.copy(), t.copy()
    f_x, f_y = np.full((1, 1), fx), np.full((1, 1), fy)
    for i in range(len(R)):
        lam = np.full(1, 1e-4)
        for _ in range(max_iter):
            Ri, ti = R[i:i + 1], t[i:i + 1]
            uv_i, _, _, J = _project_with_jacobian(Ri, ti, X_B, f_x, f_y, cx, cy, d5)
            r = uv[i:i + 1] - uv_i
            Jf = J.reshape(1, -1, 6)
            JtJ = Jf.transpose(0, 2, 1) @ Jf
            Jtr = Jf.transpose(0, 2, 1) @ r.reshape(1, -1, 1)
            delta = np.linalg.solve(JtJ + lam[:, None, None] * (JtJ * np.eye(6)), Jtr)[..., 0]
            R_new, t_new = R_from_rvec(delta[:, :3]) @ Ri, ti + delta[:, 3:]
            res_new = uv[i:i + 1] - project_poses(R_new, t_new, X_B, f_x, f_y, cx, cy, d5)[0]
            accept = bool(np.sum(res_new ** 2, axis=(1, 2))[0] <= np.sum(r ** 2, axis=(1, 2))[0])
            if accept:
                R[i], t[i] = R_new[0], t_new[0]
            lam = np.maximum(lam * 0.1, 1e-9) if accept else lam * 10.0
            if (accept and np.max(np.abs(delta)) < tol) or lam[0] > 1e6:
                break
    return R, t


def test_lm_equals_the_plain_lm_bit_for_bit_with_rejected_steps():
    """_solve_R_t (residual reused, Jacobian only for rows that go on, a rejected row's Jacobian
    kept from its unchanged pose, stopped rows compacted away) equals the plain LM in every bit.

    The starts are far off (0.3 rad, t scaled by 0.5-1.6), so some steps are rejected and rows
    stop at different iterations: every branch of the bookkeeping is taken.
    """
    _, _, _, _, uv, rvec, tvec = _session(40, seed=11)
    X_B = board_object_points(BOARD)
    rng = np.random.default_rng(12)
    R0 = R_from_rvec(rvec + rng.normal(0.0, 0.3, rvec.shape))
    t0 = tvec * rng.uniform(0.5, 1.6, (40, 1))
    d5 = dist5(DIST)
    R, t, n_iter = _solve_R_t(uv, X_B, 690.0, 712.0, 320.0, 240.0, d5, R0, t0, 10, 1e-6)
    R_p, t_p = _plain_lm(uv, X_B, 690.0, 712.0, 320.0, 240.0, d5, R0, t0, 10, 1e-6)
    assert R.tobytes() == R_p.tobytes() and t.tobytes() == t_p.tobytes()
    assert n_iter == 10  # some row ran out of iterations while others had stopped
    # and the solve went somewhere: near the poses the corners were drawn from
    assert np.median(np.linalg.norm(t - tvec, axis=1)) < 0.05


def _same_run(a, b):
    """Two optimise_seed results equal in every table value and every result entry."""
    for name in ("iterations", "errors"):
        x, y = getattr(a, name), getattr(b, name)
        assert list(x.columns) == list(y.columns)
        for c in x.columns:  # NaN where both are NaN (the last row's objective_grid_min)
            u, v = x[c].to_numpy(), y[c].to_numpy()
            assert np.array_equal(u, v, equal_nan=u.dtype.kind == "f"), (name, c)
    drop = ("timings_s",)
    assert {k: v for k, v in a.result.items() if k not in drop} == \
        {k: v for k, v in b.result.items() if k not in drop}


def test_pose_cache_runs_equal_the_runs_without_it_bit_for_bit():
    """Runs on overlapping subsets of one session share PnP rows through SeedPoseCache, and
    each run's tables equal those of the same run without the cache in every bit.

    Two folds (the session without its first, then without its last 20 frames) share their
    start solve and first iteration; the first fold again takes every row from the cache; a
    cache too small for more than a few entries keeps the results too.
    """
    from cvsflow.optimise.seed_cache import SeedPoseCache

    pairs, corners, K, *_ = _session(60, seed=13)
    kw = dict(k_iterations=4, f_init_px=(600.0, 800.0), grid_points=3, grid_levels=2,
              grid_half_width_px=16.0)
    folds = [pairs.iloc[20:], pairs.iloc[:40]]
    plain = [optimise_seed(p, corners, K, DIST, BOARD, **kw) for p in folds]
    # both walks move every iteration, so later iterations' rows (warm-started from other
    # focal lengths than the first's) are compared too
    for run in plain:
        f = run.iterations[["fx_px", "fy_px"]].to_numpy()
        assert (np.abs(np.diff(f, axis=0)).sum(axis=1) > 0).all()

    cache = SeedPoseCache(pairs, corners, BOARD)
    cached = [optimise_seed(p, corners, K, DIST, BOARD, pose_cache=cache, **kw) for p in folds]
    for a, b in zip(plain, cached, strict=True):
        _same_run(a, b)
    assert cache.n_reused > 0  # the second fold took its common rows from the first
    solved = cache.n_solved
    _same_run(plain[0], optimise_seed(folds[0], corners, K, DIST, BOARD, pose_cache=cache, **kw))
    assert cache.n_solved == solved  # the same run again: every row from the cache

    small = SeedPoseCache(pairs, corners, BOARD, max_bytes=3 * 60 * 97)  # room for 3 entries
    for p, a in zip(folds, plain, strict=True):
        _same_run(a, optimise_seed(p, corners, K, DIST, BOARD, pose_cache=small, **kw))
    assert len(small._entries) <= 3


def test_pose_cache_refuses_other_frames_starts_and_cameras():
    """A cache answers only runs on its session's pairs with its start poses and its camera."""
    from cvsflow.optimise.seed_cache import SeedPoseCache

    pairs, corners, K, *_ = _session(30, seed=14)
    kw = dict(k_iterations=1, grid_points=3, grid_levels=1)
    cache = SeedPoseCache(pairs.iloc[:25], corners, BOARD)
    with pytest.raises(OptimiseError, match="frame 125"):
        optimise_seed(pairs, corners, K, DIST, BOARD, pose_cache=cache, **kw)
    moved = pairs.iloc[:25].copy()
    moved["cvs_x_m"] += 0.01
    with pytest.raises(OptimiseError, match="other start poses"):
        optimise_seed(moved, corners, K, DIST, BOARD, pose_cache=cache, **kw)
    optimise_seed(pairs.iloc[:25], corners, K, DIST, BOARD, pose_cache=cache, **kw)
    K2 = K.copy()
    K2[0, 2] += 1.0
    with pytest.raises(OptimiseError, match="another camera"):
        optimise_seed(pairs.iloc[:25], corners, K2, DIST, BOARD, pose_cache=cache, **kw)


def test_pose_cache_solves_the_rows_no_run_on_the_same_walk_had():
    """SeedPoseCache.solve asks for exactly the (candidate, frame) rows it lacks on that walk,
    returns the cached rows for the others, and keeps walks apart."""
    from cvsflow.optimise.seed_cache import SeedPoseCache

    pairs, corners, *_ = _session(10, seed=15)
    cache = SeedPoseCache(pairs, corners, BOARD)
    asked = []

    def stack(frame_rows, fx_rows, fy_rows, R, t):  # any function of each row's own inputs
        asked.append(frame_rows.tolist())
        return R + fx_rows[:, None, None], t + fy_rows[:, None]

    rng = np.random.default_rng(16)
    cands = np.array([[700.0, 700.0], [716.0, 700.0]])
    walk = ((700.0, 700.0),)
    a, b = pairs.iloc[:6], pairs.iloc[3:]  # frames 3, 4, 5 in both
    start_a = rng.normal(size=(12, 3, 3)), rng.normal(size=(12, 3))
    start_b = rng.normal(size=(14, 3, 3)), rng.normal(size=(14, 3))
    R_a, t_a = cache.solve(walk, cands, cache.positions(a), *start_a, stack)
    R_b, t_b = cache.solve(walk, cands, cache.positions(b), *start_b, stack)
    assert asked == [list(range(6)) * 2, [3, 4, 5, 6] * 2]
    for k in range(2):  # shared frames from run a, new ones solved from run b's starts
        np.testing.assert_array_equal(R_b[7 * k:7 * k + 3], R_a[6 * k + 3:6 * k + 6])
        np.testing.assert_array_equal(R_b[7 * k + 3:7 * k + 7],
                                      start_b[0][7 * k + 3:7 * k + 7] + cands[k, 0])
        np.testing.assert_array_equal(t_b[7 * k + 3:7 * k + 7],
                                      start_b[1][7 * k + 3:7 * k + 7] + cands[k, 1])
    assert (cache.n_solved, cache.n_reused) == (20, 6)
    cache.solve(walk + ((716.0, 700.0),), cands, cache.positions(b), *start_b, stack)
    assert asked[-1] == list(range(7)) * 2  # another walk: nothing shared
