"""Se3Share: what the se3 fits of one session share gives the fits they had alone, bit for bit."""

import numpy as np
import pandas as pd
import pytest

from cvsflow.exceptions import OptimiseError
from cvsflow.optimise import Se3Share, apply_se3, optimise_se3, solve_pnp_frames
from cvsflow.optimise.se3_sim import simulate_session


@pytest.fixture(scope="module")
def session():
    return simulate_session(4, duration_s=8.0)


def test_share_pnp_equals_solving_the_frames_alone(session):
    s = session
    share = Se3Share(s["corners"], s["bodies"], s["board"])
    K, dist = np.asarray(s["camera"]["K"]), np.asarray(s["camera"]["dist"])
    rows = np.arange(0, share.frame.size, 3)
    T, ok = share.pnp(rows, K, dist)
    T_ref, ok_ref = solve_pnp_frames(share.uv[rows], share.p_B, K, dist)
    assert np.array_equal(ok, ok_ref) and np.array_equal(T, T_ref, equal_nan=True)
    T2, _ = share.pnp(np.arange(share.frame.size), K, dist)  # a superset: only the rest solved
    assert np.array_equal(T2[rows], T, equal_nan=True)
    assert share.n_pnp_solved == share.frame.size and share.n_pnp_reused == rows.size


def test_folds_with_a_share_equal_folds_alone(session):
    """Two folds' fits and held-out tables with one share equal those made without."""
    s = session
    args = (s["corners"], s["bodies"], s["camera"], s["board"], s["truth"]["dt_offset_s"])
    frames = np.sort(s["corners"]["frame"].unique())
    share = Se3Share(s["corners"], s["bodies"], s["board"])
    third = frames.size // 3
    for test in (frames[:third], frames[third:2 * third]):
        train = np.setdiff1d(frames, test)
        alone = optimise_se3(*args, frames=train)
        shared = optimise_se3(*args, frames=train, share=share)
        for res in (alone.result, shared.result):
            res.pop("time_s")
        assert repr(alone.result) == repr(shared.result)
        pd.testing.assert_frame_equal(alone.errors, shared.errors, check_exact=True)
        held_alone = apply_se3(alone.result, s["corners"], s["bodies"], s["board"], frames=test)
        held_shared = apply_se3(shared.result, s["corners"], s["bodies"], s["board"], frames=test,
                                share=share)
        pd.testing.assert_frame_equal(held_alone, held_shared, check_exact=True)
    assert share.n_pnp_reused > 0


def test_share_refuses_other_tables(session):
    s = session
    share = Se3Share(s["corners"], s["bodies"], s["board"])
    with pytest.raises(OptimiseError, match="not the one the share was made from"):
        optimise_se3(s["corners"].copy(), s["bodies"], s["camera"], s["board"],
                     s["truth"]["dt_offset_s"], share=share)
    with pytest.raises(OptimiseError, match="no corners"):
        share.rows([int(share.frame.max()) + 1])


def test_fit_without_the_per_frame_table_has_the_same_result(session):
    """per_frame=False (the held-out folds) leaves out only the errors table."""
    s = session
    args = (s["corners"], s["bodies"], s["camera"], s["board"], s["truth"]["dt_offset_s"])
    full, bare = optimise_se3(*args), optimise_se3(*args, per_frame=False)
    for res in (full.result, bare.result):
        res.pop("time_s")
    assert repr(full.result) == repr(bare.result) and bare.errors.empty and len(full.errors) > 0
    pd.testing.assert_frame_equal(full.iterations, bare.iterations, check_exact=True)
