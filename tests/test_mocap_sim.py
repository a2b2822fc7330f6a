"""SimMocap: an OdometrySource of the true pose with noise, latency, dropouts, and the
motioncapture library's mock backend."""

from __future__ import annotations

import asyncio
import itertools
import time

import numpy as np
import pytest

from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.sources import OdometrySource
from sim_harness.mocap import MOCK_RATE_HZ, SimMocap
from sim_harness.px4 import TruePose


class MovingPose:
    """x = t (m) since creation: a pose that changes every call, stamped with its own time."""

    def __init__(self) -> None:
        self.t0 = time.monotonic()

    def __call__(self) -> TruePose:
        t = time.monotonic()
        return TruePose(np.array([t - self.t0, 2.0, 1.5]), np.zeros(3), quat_from_yaw(0.3), t)


async def collect(mocap: SimMocap, n: int, pause_s: float = 0.0) -> list:
    out = []
    async with mocap:
        async for s in mocap.samples():
            out.append(s)
            if len(out) == n:
                break
            if pause_s:
                await asyncio.sleep(pause_s)
    return out


def test_implements_the_odometry_source_protocol() -> None:
    assert isinstance(SimMocap(MovingPose()), OdometrySource)


async def test_samples_follow_the_true_pose_at_the_configured_rate() -> None:
    pose = MovingPose()
    samples = await collect(SimMocap(pose, rate_hz=100.0), 30)
    arrivals = np.array([s.t_arrival_mono_s for s in samples])
    assert np.all(np.diff(arrivals) > 0)
    assert arrivals[-1] - arrivals[0] >= (len(arrivals) - 2) / 100.0  # on the 100 Hz grid, not faster
    for s in samples:
        measured_at = s.pos_world_m[0] + pose.t0
        assert 0.0 <= s.t_arrival_mono_s - measured_at < 0.05  # a current pose, delivered after it
        assert s.pos_world_m[1:] == pytest.approx([2.0, 1.5])
        assert s.quat_world_body == pytest.approx(quat_from_yaw(0.3))


async def test_latency_delivers_each_pose_late_by_latency_s() -> None:
    pose = MovingPose()
    samples = await collect(SimMocap(pose, rate_hz=120.0, latency_s=0.05), 20)
    for s in samples:
        measured_at = s.pos_world_m[0] + pose.t0
        assert s.t_arrival_mono_s - measured_at >= 0.05 - 1e-3


async def test_noise_is_seeded_and_has_the_configured_spread() -> None:
    fixed = lambda: TruePose(np.zeros(3), np.zeros(3), np.array([1.0, 0, 0, 0]), 0.0)  # noqa: E731
    a = await collect(SimMocap(fixed, rate_hz=500.0, noise_m=0.01, seed=3), 200)
    b = await collect(SimMocap(fixed, rate_hz=500.0, noise_m=0.01, seed=3), 200)
    c = await collect(SimMocap(fixed, rate_hz=500.0, noise_m=0.01, seed=4), 200)
    pa = np.array([s.pos_world_m for s in a])
    assert np.array_equal(pa, np.array([s.pos_world_m for s in b]))
    assert not np.array_equal(pa, np.array([s.pos_world_m for s in c]))
    assert pa.std() == pytest.approx(0.01, rel=0.15)
    assert np.abs(pa.mean(axis=0)).max() < 0.003


async def test_dropout_loses_about_the_configured_fraction() -> None:
    mocap = SimMocap(MovingPose(), rate_hz=500.0, dropout=0.3, seed=1)
    await collect(mocap, 200)
    assert mocap.dropped / mocap.taken == pytest.approx(0.3, abs=0.08)


async def test_pause_stops_the_feed_and_resume_restarts_it() -> None:
    mocap = SimMocap(MovingPose(), rate_hz=100.0)
    async with mocap:
        stream = mocap.samples()
        await anext(stream)
        mocap.pause()
        with pytest.raises(TimeoutError):
            async with asyncio.timeout(0.3):
                await anext(stream)
        mocap.resume()
        async with asyncio.timeout(1.0):
            sample = await anext(stream)
        assert sample.t_arrival_mono_s > 0
        await stream.aclose()


async def test_a_slow_consumer_gets_fresh_samples_not_a_backlog() -> None:
    samples = await collect(SimMocap(MovingPose(), rate_hz=120.0, latency_s=0.05), 4, pause_s=0.2)
    for prev, cur in itertools.pairwise(samples):
        assert cur.t_arrival_mono_s - prev.t_arrival_mono_s >= 0.2
        measured_at_gap = cur.pos_world_m[0] - prev.pos_world_m[0]
        assert measured_at_gap >= 0.2 - 0.02  # a sample measured after the pause, not before it


async def test_motioncapture_mock_backend_runs_the_library_path() -> None:
    """Poses pass through motioncapture's mock RigidBody (float32) at the library's 100 Hz."""
    pose = MovingPose()
    mocap = SimMocap(pose, backend="motioncapture-mock")
    assert mocap.rate_hz == MOCK_RATE_HZ
    samples = await collect(mocap, 10)
    for s in samples:
        assert s.pos_world_m[1:] == pytest.approx([2.0, 1.5], abs=1e-6)
        assert 0.0 <= s.t_arrival_mono_s - (s.pos_world_m[0] + pose.t0) < 0.05
        assert s.quat_world_body == pytest.approx(quat_from_yaw(0.3), abs=1e-6)
        assert np.float32(s.pos_world_m[0]) == s.pos_world_m[0]  # float32 from the library
    assert samples[-1].t_arrival_mono_s - samples[0].t_arrival_mono_s >= 8 * 0.0095  # library paced


def test_bad_parameters_are_clear_errors() -> None:
    with pytest.raises(ValueError, match="dropout"):
        SimMocap(MovingPose(), dropout=1.5)
    with pytest.raises(ValueError, match="backend"):
        SimMocap(MovingPose(), backend="vicon")  # type: ignore[arg-type]
