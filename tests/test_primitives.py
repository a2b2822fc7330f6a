"""Cubic Bézier motion primitives."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet, bezier_position

SIM = PrimitiveSet(scale_m=1.0, duration_s=1.0)
REAL = PrimitiveSet(scale_m=0.5, duration_s=1.0)
action = st.integers(0, 17)
vel = st.tuples(*[st.floats(-2, 2)] * 3).map(np.array)


def test_default_set_is_the_18_forward_biased_directions():
    """18 distinct directions: forward in {1, 0}, lateral and vertical in {-1, 0, 1}."""
    dirs = np.array(DEFAULT_DIRECTIONS)
    assert dirs.shape == (18, 3)
    assert len({tuple(d) for d in dirs}) == 18
    assert set(dirs[:, 0]) == {0, 1} and set(dirs[:, 1]) == {-1, 0, 1} and set(dirs[:, 2]) == {-1, 0, 1}
    assert (dirs[:, 0] >= 0).all(), "no primitive goes backwards"


@given(action, vel)
def test_end_point_is_scaled_direction(a, v0):
    """Whatever the start velocity, a primitive ends at scale * direction after duration_s."""
    for ps in (SIM, REAL):
        disp, _ = ps.sample(a, v0, ps.duration_s)
        np.testing.assert_allclose(disp, np.array(DEFAULT_DIRECTIONS[a]) * ps.scale_m, atol=1e-12)


def test_real_flight_scale_is_half_a_metre_per_axis():
    """Action (1, 1, 1) at real-flight scale ends 0.5 m forward, left and up."""
    a = DEFAULT_DIRECTIONS.index((1, 1, 1))
    np.testing.assert_allclose(REAL.end_displacement_m(a), [0.5, 0.5, 0.5])


@given(action, action, vel)
def test_consecutive_primitives_are_c1(a1, a2, v0):
    """The next primitive starts with the position and velocity the previous one ended with."""
    _d1, v1 = SIM.sample(a1, v0, SIM.duration_s)
    d2, v2 = SIM.sample(a2, SIM.end_velocity_m_s(a1), 0.0)
    np.testing.assert_allclose(d2, 0.0, atol=1e-12)  # relative to the previous end point d1
    np.testing.assert_allclose(v2, v1, atol=1e-9)


@given(action, vel, st.floats(0.0, 1.0))
def test_velocity_is_derivative_of_position(a, v0, t):
    """Sampled velocity equals the finite difference of sampled position."""
    h = 1e-6
    t = min(max(t, h), 1.0 - h)
    p_plus, _ = SIM.sample(a, v0, t + h)
    p_minus, _ = SIM.sample(a, v0, t - h)
    _, v = SIM.sample(a, v0, t)
    np.testing.assert_allclose((p_plus - p_minus) / (2 * h), v, atol=1e-5)


def test_bernstein_form_at_midpoint():
    """C(1/2) = (P0 + 3 P1 + 3 P2 + P3) / 8 for a cubic."""
    ctrl = np.array([[0, 0, 0], [1, 2, 0], [3, 2, 1], [4, 0, 2]], float)
    np.testing.assert_allclose(
        bezier_position(ctrl, 0.5), (ctrl[0] + 3 * ctrl[1] + 3 * ctrl[2] + ctrl[3]) / 8
    )


def test_duration_scales_time():
    """With a 2 s step, the end is reached at t = 2 s, and halfway there the curve is mid-way."""
    slow = PrimitiveSet(scale_m=1.0, duration_s=2.0)
    a = DEFAULT_DIRECTIONS.index((1, 0, 0))
    np.testing.assert_allclose(slow.sample(a, slow.end_velocity_m_s(a), 2.0)[0], [1, 0, 0])
    np.testing.assert_allclose(slow.sample(a, slow.end_velocity_m_s(a), 1.0)[0], [0.5, 0, 0])


def test_batched_actions():
    """Arrays of actions and start velocities sample in one call."""
    acts = np.arange(18)
    disp, vel_ = SIM.sample(acts, np.zeros((18, 3)), 1.0)
    np.testing.assert_allclose(disp, np.array(DEFAULT_DIRECTIONS, float))
    assert vel_.shape == (18, 3)


@pytest.mark.parametrize("bad", [-1, 18])
def test_out_of_range_action_is_an_error(bad):
    with pytest.raises(IndexError):
        SIM.end_displacement_m(bad)


def test_bad_set_is_rejected():
    with pytest.raises(ValueError):
        PrimitiveSet(scale_m=0.0)
    with pytest.raises(ValueError):
        PrimitiveSet(directions=((1, 0),))
