"""The paper's reward, every branch and boundary."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from quadnav_onboard.reward import RewardParams, reward

P = RewardParams()


def r(d_prev, d_now, deviated=False, collided=False, params=P):
    return float(reward(d_prev, d_now, deviated, collided, params))


def test_paper_constants_are_the_defaults():
    assert (P.r_lower, P.r_upper, P.dd_lower_m, P.dd_upper_m) == (0.0, 0.5, -1.0, 1.0)
    assert (P.deviation_penalty, P.collision_penalty, P.max_deviation_m) == (-0.5, -1.0, 5.0)


def test_distance_growing_fast_gives_r_lower():
    """Δd > Δd_u: R = R_l / d_t (0 with the paper's constants)."""
    assert r(1.0, 3.0) == pytest.approx(0.0)
    assert r(1.0, 3.0, params=RewardParams(r_lower=0.1)) == pytest.approx(0.1 / 3.0)


def test_distance_shrinking_fast_gives_r_upper():
    """Δd < Δd_l: R = R_u / d_t."""
    assert r(4.0, 2.0) == pytest.approx(0.5 / 2.0)


def test_linear_branch_middle():
    """Δd = 0: halfway between R_l and R_u, divided by d_t."""
    assert r(2.0, 2.0) == pytest.approx(0.25 / 2.0)


@pytest.mark.parametrize(("dd", "expected_num"), [(1.0, 0.0), (-1.0, 0.5), (0.5, 0.125), (-0.5, 0.375)])
def test_linear_branch_and_its_boundaries(dd, expected_num):
    """At Δd = Δd_u the reward is R_l/d_t, at Δd = Δd_l it is R_u/d_t, linear in between."""
    d_now = 2.0
    assert r(d_now - dd, d_now) == pytest.approx(expected_num / d_now)


@given(st.floats(0, 20), st.floats(0.3, 20))
def test_shaping_is_continuous_and_bounded(d_prev, d_now):
    """Outside the penalties, 0 <= R <= R_u / d_t."""
    val = r(d_prev, d_now)
    assert 0.0 <= val <= 0.5 / d_now + 1e-12


def test_d_t_floor_caps_the_reward():
    """d_t -> 0 is floored at d_floor_m: the reward stays finite."""
    assert r(0.5, 0.0) == pytest.approx(0.375 / P.d_floor_m)
    assert np.isfinite(r(0.0, 0.0))


def test_deviation_penalty():
    assert r(1.0, 1.0, deviated=True) == -0.5


def test_collision_penalty_takes_precedence():
    assert r(1.0, 1.0, collided=True) == -1.0
    assert r(1.0, 1.0, deviated=True, collided=True) == -1.0


def test_vectorised():
    out = reward(
        np.array([2.0, 4.0, 1.0, 1.0]),
        np.array([2.0, 2.0, 1.0, 1.0]),
        np.array([0, 0, 1, 0]),
        np.array([0, 0, 0, 1]),
    )
    np.testing.assert_allclose(out, [0.125, 0.25, -0.5, -1.0])


def test_bad_params_rejected():
    with pytest.raises(ValueError):
        RewardParams(dd_lower_m=1.0, dd_upper_m=1.0)
    with pytest.raises(ValueError):
        RewardParams(d_floor_m=0.0)
