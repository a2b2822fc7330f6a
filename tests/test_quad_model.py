"""Kinematic quad model: tracks setpoints like a PX4 position loop, within its limits."""

import numpy as np

from sim_harness.quad import QuadParams, QuadState, step, track

P = QuadParams()


def test_converges_to_a_fixed_setpoint_without_overshoot():
    """Critically damped: reaches a 1 m step within 2 s and never overshoots."""
    s = QuadState.at_rest(np.zeros(3))
    target = np.array([[1.0, 0.0, 0.0]])
    xs = []
    for _ in range(int(2.0 / P.dt_s)):
        s = step(s, target, None, P)
        xs.append(s.pos_m[0, 0])
    assert abs(xs[-1] - 1.0) < 0.02
    assert max(xs) <= 1.0 + 1e-6


def test_speed_and_acceleration_limits_hold():
    s = QuadState.at_rest(np.zeros(3))
    target = np.array([[100.0, 0.0, 0.0]])
    prev_v = s.vel_m_s.copy()
    for _ in range(200):
        s = step(s, target, None, P)
        assert np.linalg.norm(s.vel_m_s) <= P.max_speed_m_s + 1e-9
        assert np.linalg.norm(s.vel_m_s - prev_v) / P.dt_s <= P.max_accel_m_s2 + 1e-9
        prev_v = s.vel_m_s.copy()


def test_track_returns_the_whole_trail_vectorised():
    """track() follows a K-step setpoint sequence for N quads and returns K+1 positions each."""
    n, k = 4, 20
    s = QuadState.at_rest(np.zeros((n, 3)))
    tgt = np.linspace(0, 1, k)[:, None, None] * np.ones((k, n, 3))
    end, trail = track(s, tgt, np.zeros_like(tgt), P)
    assert trail.shape == (k + 1, n, 3)
    np.testing.assert_array_equal(trail[0], 0.0)
    np.testing.assert_array_equal(trail[-1], end.pos_m)
    assert (np.diff(trail[:, 0, 0]) >= -1e-12).all()
