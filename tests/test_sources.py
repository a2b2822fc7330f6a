"""Hardware sources without hardware: PNG replay, mocap through the motioncapture library's mock
backend, and the mocap frame transform (the D435 over V4L2: tests/test_uvc.py)."""

from __future__ import annotations

import asyncio
from pathlib import Path

import cv2
import numpy as np
import pytest

from quadnav_onboard.frames import quat_from_rotmat, quat_from_yaw, quat_to_rotmat, quat_to_yaw
from quadnav_onboard.sources.mocap import MocapError, MocapOdometrySource, MocapTransform
from quadnav_onboard.sources.replay import ReplayDepthSource, ReplayError

Y_UP = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))


async def test_replay_plays_16_bit_pngs_in_name_order(tmp_path: Path) -> None:
    for i in (2, 1):
        cv2.imwrite(str(tmp_path / f"{i:04d}.png"), np.full((48, 64), 1000 * i, np.uint16))
    async with ReplayDepthSource(tmp_path, fps=200.0, loop=False) as src:
        got = [f async for f in src.frames()]
    assert [int(f.depth_mm[0, 0]) for f in got] == [1000, 2000]
    assert all(f.depth_mm.dtype == np.uint16 for f in got)


async def test_replay_refuses_8_bit_images_and_empty_folders(tmp_path: Path) -> None:
    with pytest.raises(ReplayError, match=r"no \.png"):
        async with ReplayDepthSource(tmp_path):
            pass
    cv2.imwrite(str(tmp_path / "a.png"), np.zeros((8, 8), np.uint8))
    async with ReplayDepthSource(tmp_path, fps=100.0) as src:
        with pytest.raises(ReplayError, match=r"a\.png"):
            await anext(src.frames())


def test_quat_from_rotmat_inverts_quat_to_rotmat() -> None:
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q = -q if q[0] < 0 else q
        assert np.allclose(quat_from_rotmat(quat_to_rotmat(q)), q, atol=1e-9)
    with pytest.raises(ValueError):
        quat_from_rotmat(np.diag([1.0, 1.0, -1.0]))


def test_optitrack_y_up_maps_into_our_z_up_world() -> None:
    tf = MocapTransform(Y_UP, (0.5, 0.0, 0.0))
    # mocap (x, y=up, z) = (1, 2, 3): 2 m up, 3 m along mocap z = 3 m to the right (world -y)
    pos, q = tf.apply(np.array([1.0, 2.0, 3.0]), np.array([1.0, 0.0, 0.0, 0.0]))
    assert np.allclose(pos, [1.5, -3.0, 2.0]) and np.allclose(q, [1, 0, 0, 0])
    # a yaw of 0.4 rad about the mocap's up axis (y) is a yaw of 0.4 rad about world z
    half = 0.2
    q_mocap = np.array([np.cos(half), 0.0, np.sin(half), 0.0])
    _, q = tf.apply(np.zeros(3), q_mocap)
    assert np.isclose(quat_to_yaw(q), 0.4) and np.allclose(np.abs(q), np.abs(quat_from_yaw(0.4)), atol=1e-12)


async def test_mocap_source_runs_the_real_library_mock_backend() -> None:
    tf = MocapTransform(Y_UP, (0.0, 0.0, 0.0))
    src = MocapOdometrySource(
        "mock", "localhost", "quad", tf, connect_args={"rigid_bodies": "quad(1,2,3,1,0,0,0)"}
    )
    async with src:
        s = await asyncio.wait_for(anext(src.samples()), 5)
    assert np.allclose(s.pos_world_m, [1.0, -3.0, 2.0]) and s.t_arrival_mono_s > 0


async def test_mocap_connection_failure_names_system_and_host() -> None:
    src = MocapOdometrySource("no-such-system", "10.0.0.9", "quad", MocapTransform(Y_UP, (0, 0, 0)))
    with pytest.raises(MocapError, match=r"no-such-system at '10\.0\.0\.9'"):
        async with src:
            pass
