"""Hardware sources without hardware: UVC over a fake capture (spec=cv2.VideoCapture), PNG replay,
mocap through the motioncapture library's mock backend, and the mocap frame transform."""

from __future__ import annotations

import asyncio
from pathlib import Path
from unittest import mock

import cv2
import numpy as np
import pytest

from quadnav_onboard.frames import quat_from_rotmat, quat_from_yaw, quat_to_rotmat, quat_to_yaw
from quadnav_onboard.sources.mocap import MocapError, MocapOdometrySource, MocapTransform
from quadnav_onboard.sources.replay import ReplayDepthSource, ReplayError
from quadnav_onboard.sources.uvc import Z16, DepthSourceError, UvcDepthSource, raw_to_depth_mm

Y_UP = ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0))


def test_raw_z16_bytes_become_uint16_millimetres() -> None:
    depth = np.arange(32 * 40, dtype=np.uint16).reshape(32, 40) * 7
    raw = depth.astype("<u2").view(np.uint8).reshape(1, -1)
    assert np.array_equal(raw_to_depth_mm(raw, 40, 32), depth)
    assert raw_to_depth_mm(depth, 40, 32) is depth
    with pytest.raises(ValueError, match="RGB"):
        raw_to_depth_mm(np.zeros((32, 40, 3), np.uint8), 40, 32)


def fake_capture(frames: list[tuple[bool, np.ndarray | None]], opened: bool = True) -> mock.Mock:
    cap = mock.create_autospec(cv2.VideoCapture, instance=True)
    cap.isOpened.return_value = opened
    cap.read.side_effect = frames
    return cap


async def test_uvc_source_asks_v4l2_for_raw_z16_and_yields_uint16_frames() -> None:
    depth = np.full((240, 424), 1234, np.uint16)
    cap = fake_capture([(True, depth.view(np.uint8).reshape(1, -1))] * 3)
    factory = mock.Mock(return_value=cap)
    async with UvcDepthSource("/dev/video2", 424, 240, 30, capture_factory=factory) as src:
        frames = src.frames()
        f = await anext(frames)
    factory.assert_called_once_with("/dev/video2", cv2.CAP_V4L2)
    props = {c.args[0]: c.args[1] for c in cap.set.call_args_list}
    assert props[cv2.CAP_PROP_FOURCC] == Z16 and props[cv2.CAP_PROP_CONVERT_RGB] == 0
    assert props[cv2.CAP_PROP_FORMAT] == -1
    assert (props[cv2.CAP_PROP_FRAME_WIDTH], props[cv2.CAP_PROP_FRAME_HEIGHT], props[cv2.CAP_PROP_FPS]) == (
        424,
        240,
        30,
    )
    assert f.depth_mm.dtype == np.uint16 and f.depth_mm.shape == (240, 424) and f.seq == 1
    assert int(f.depth_mm[0, 0]) == 1234


async def test_uvc_device_index_and_open_failure_are_named() -> None:
    factory = mock.Mock(return_value=fake_capture([], opened=False))
    with pytest.raises(DepthSourceError, match="'2'"):
        async with UvcDepthSource("2", capture_factory=factory):
            pass
    factory.assert_called_once_with(2, cv2.CAP_V4L2)


async def test_uvc_gives_up_after_repeated_read_failures() -> None:
    cap = fake_capture([(False, None)] * 5)
    async with UvcDepthSource(
        "/dev/video0", capture_factory=mock.Mock(return_value=cap), max_consecutive_failures=5
    ) as src:
        with pytest.raises(DepthSourceError, match="5 reads in a row"):
            await anext(src.frames())


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
