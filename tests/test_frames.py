"""Frame conversions: world<->heading/body, ENU<->NED, quaternions."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from quadnav_onboard import frames

finite = st.floats(-1e3, 1e3, allow_nan=False)
vec3 = st.tuples(finite, finite, finite).map(np.array)
yaw = st.floats(-10.0, 10.0, allow_nan=False)


@given(vec3, yaw)
def test_world_body_world_is_identity(v, y):
    """world -> body -> world returns the vector unchanged."""
    np.testing.assert_allclose(frames.body_to_world(frames.world_to_body(v, y), y), v, atol=1e-9)


@given(vec3, yaw)
def test_rotation_preserves_length_and_height(v, y):
    """A yaw rotation keeps the norm and the z component."""
    b = frames.world_to_body(v, y)
    assert np.isclose(np.linalg.norm(b), np.linalg.norm(v), atol=1e-9)
    assert np.isclose(b[2], v[2])


def test_world_to_body_known_case():
    """A quad facing world +y sees world +y as forward and world +x on its right."""
    # Quad facing world +y (yaw = +90 deg): a world +y vector is body forward (+x).
    np.testing.assert_allclose(frames.world_to_body([0, 1, 0], np.pi / 2), [1, 0, 0], atol=1e-12)
    # ... and a world +x vector is to its right (body -y).
    np.testing.assert_allclose(frames.world_to_body([1, 0, 0], np.pi / 2), [0, -1, 0], atol=1e-12)


def test_rotmat_matches_body_to_world():
    """rotmat_yaw is the matrix of body_to_world."""
    rng = np.random.default_rng(0)
    v, y = rng.normal(size=3), 0.7
    np.testing.assert_allclose(frames.rotmat_yaw(y) @ v, frames.body_to_world(v, y), atol=1e-12)


@given(vec3)
def test_enu_ned_round_trip(v):
    """ENU -> NED -> ENU is identity; NED flips y and z."""
    n = frames.flu_to_frd(v)
    np.testing.assert_allclose(n, [v[0], -v[1], -v[2]])
    np.testing.assert_allclose(frames.frd_to_flu(n), v)


def test_altitude_up_is_negative_down():
    """2 m above the floor in the world is z = -2 in NED."""
    assert frames.flu_to_frd([0.0, 0.0, 2.0])[2] == -2.0


@given(yaw)
def test_yaw_conversions_invert(y):
    """World yaw -> PX4 yaw -> world yaw is identity modulo 2 pi; left turn is negative in NED."""
    back = frames.yaw_frd_to_flu(frames.yaw_flu_to_frd(y))
    assert np.isclose(np.cos(back), np.cos(y)) and np.isclose(np.sin(back), np.sin(y))
    assert np.isclose(frames.yaw_flu_to_frd(0.3), -0.3)


@given(yaw)
def test_quat_from_yaw_round_trip(y):
    """quat_to_yaw(quat_from_yaw(y)) == wrap(y) and its matrix is rotmat_yaw."""
    q = frames.quat_from_yaw(y)
    assert np.isclose(frames.wrap_angle(frames.quat_to_yaw(q) - y), 0.0, atol=1e-9)
    np.testing.assert_allclose(frames.quat_to_rotmat(q), frames.rotmat_yaw(y), atol=1e-12)


def test_quat_multiply_composes_rotations():
    """q(a) * q(b) == q(a + b) for rotations about the same axis."""
    np.testing.assert_allclose(
        frames.quat_multiply(frames.quat_from_yaw(0.4), frames.quat_from_yaw(0.5)),
        frames.quat_from_yaw(0.9),
        atol=1e-12,
    )


def test_quat_world_to_ned_flips_yaw():
    """An FLU body yawed +a in the world is an FRD body yawed -a in NED; the map is an involution."""
    q_world = frames.quat_from_yaw(0.6)
    q_ned = frames.quat_world_to_ned(q_world)
    assert np.isclose(frames.quat_to_yaw(q_ned), -0.6)
    np.testing.assert_allclose(frames.quat_world_to_ned(q_ned), q_world, atol=1e-12)


def test_zero_quaternion_rejected():
    """A zero quaternion is an error, not a silent NaN matrix."""
    import pytest

    with pytest.raises(ValueError, match="norm"):
        frames.quat_to_rotmat([0.0, 0.0, 0.0, 0.0])
