"""Rough path and moving setpoint."""

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from quadnav_onboard.path import RoughPath

PATH = RoughPath.straight([0, 0, 2], [60, 0, 2], speed_m_s=1.0)


def test_setpoint_advances_at_speed_and_stops_at_goal():
    """The moving setpoint moves speed*t along the path from the start and stops at the goal."""
    np.testing.assert_allclose(PATH.setpoint_at(0.0), [0, 0, 2])
    np.testing.assert_allclose(PATH.setpoint_at(12.5), [12.5, 0, 2])
    np.testing.assert_allclose(PATH.setpoint_at(1000.0), [60, 0, 2])
    np.testing.assert_allclose(PATH.setpoint_at(-3.0), [0, 0, 2])
    assert PATH.duration_s == 60.0


def test_progress_and_deviation_of_an_offset_point():
    """Navigation distance is the arc length of the closest point; deviation is the distance to it."""
    arc, dev = PATH.closest([20.0, 3.0, 6.0])
    assert arc == pytest.approx(20.0)
    assert dev == pytest.approx(5.0)
    assert PATH.progress_m([-5.0, 0.0, 2.0]) == pytest.approx(0.0)
    assert PATH.progress_m([70.0, 0.0, 2.0]) == pytest.approx(60.0)


def test_polyline_progress_and_setpoint_turn_the_corner():
    """On an L-shaped path, arc length accumulates across segments."""
    p = RoughPath(np.array([[0, 0, 2], [10, 0, 2], [10, 10, 2]], float), speed_m_s=2.0)
    assert p.length_m == pytest.approx(20.0)
    np.testing.assert_allclose(p.setpoint_at(7.5), [10, 5, 2])
    assert p.progress_m([11.0, 4.0, 2.0]) == pytest.approx(14.0)
    assert p.yaw_at(15.0) == pytest.approx(np.pi / 2)
    # the heading frame of a quad: the heading of the segment it has progressed along
    np.testing.assert_allclose(p.heading_at([[5.0, 1.0, 2.0], [11.0, 4.0, 2.0]]), [0.0, np.pi / 2])


def test_batched_closest_matches_single():
    """closest() on (N, 3) equals closest() on each row."""
    rng = np.random.default_rng(1)
    pts = rng.uniform(-5, 65, size=(16, 3))
    arc, dev = PATH.closest(pts)
    for i, q in enumerate(pts):
        a, d = PATH.closest(q)
        assert arc[i] == pytest.approx(a) and dev[i] == pytest.approx(d)


@given(st.floats(0, 60), st.floats(-4, 4), st.floats(-4, 4), st.floats(-3.2, 3.2))
def test_relative_state_is_setpoint_minus_quad_in_heading_frame(s, dy, dz, yaw):
    """The state vector has the length of setpoint - quad, and is that vector when yaw = 0."""
    sp = PATH.point_at(s)
    q = sp + np.array([-1.0, dy, dz])
    rel = PATH.relative_state(sp, q, yaw)
    assert np.linalg.norm(rel) == pytest.approx(np.linalg.norm(sp - q))
    np.testing.assert_allclose(PATH.relative_state(sp, q, 0.0), sp - q, atol=1e-12)


@pytest.mark.parametrize(
    "wps",
    [
        np.zeros((1, 3)),
        np.zeros((2, 2)),
        np.array([[0, 0, 0], [0, 0, 0]], float),
        np.array([[0, 0, np.nan], [1, 0, 0]]),
    ],
)
def test_bad_paths_are_rejected(wps):
    """Too few, wrong-shape, repeated or non-finite waypoints are errors."""
    with pytest.raises(ValueError):
        RoughPath(wps)


def test_non_positive_speed_is_rejected():
    with pytest.raises(ValueError, match="speed"):
        RoughPath.straight([0, 0, 0], [1, 0, 0], speed_m_s=0.0)
