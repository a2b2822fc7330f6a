"""SimDepthCamera: a DepthSource that renders the world from a pose at a fixed frame rate."""

from __future__ import annotations

import asyncio
import itertools
import time

import numpy as np
import pytest

from quadnav_onboard.config import parse_config
from quadnav_onboard.sources import DepthSource
from sim_harness.camera import SimDepthCamera
from sim_harness.noise import DepthNoise
from sim_harness.px4 import TruePose
from sim_harness.render import CameraModel
from sim_harness.world import parse_world

SMALL = CameraModel(64, 48)
WALL = parse_world({
    "name": "wall", "path": {"waypoints": [[0, 0, 1], [10, 0, 1]]},
    "bounds": {"floor_z": 0.0, "ceiling_z": 5.0},
    "obstacles": [{"type": "box", "center": [3.0, 0.0, 1.0], "size": [0.2, 8.0, 8.0]}],
})


def pose_at(x: float) -> TruePose:
    return TruePose(np.array([x, 0.0, 1.0]), np.zeros(3), np.array([1.0, 0.0, 0.0, 0.0]), time.monotonic())


async def take(cam: SimDepthCamera, n: int, pause_s: float = 0.0) -> list:
    out = []
    async with cam:
        async for frame in cam.frames():
            out.append((frame, time.monotonic()))
            if len(out) == n:
                break
            await asyncio.sleep(pause_s)
    return out


def test_implements_the_depth_source_protocol() -> None:
    assert isinstance(SimDepthCamera(WALL, lambda: pose_at(0.0)), DepthSource)


async def test_frames_are_uint16_mm_of_the_world_at_the_true_pose() -> None:
    """The wall's face is 2.9 m ahead: the image centre reads 2900 mm; moving closer reads less."""
    x = {"now": 0.0}
    cam = SimDepthCamera(WALL, lambda: pose_at(x["now"]), camera=SMALL, fps=30.0)
    (first, _), = await take(cam, 1)
    assert first.depth_mm.dtype == np.uint16 and first.depth_mm.shape == (48, 64)
    assert first.depth_mm[24, 32] == pytest.approx(2900, abs=20)
    x["now"] = 1.0
    (second, _), = await take(cam, 1)
    assert second.depth_mm[24, 32] == pytest.approx(1900, abs=20)


async def test_frames_come_on_the_fps_grid_with_increasing_seq_and_capture_times() -> None:
    cam = SimDepthCamera(WALL, lambda: pose_at(0.0), camera=SMALL, fps=30.0)
    frames = [f for f, _ in await take(cam, 8)]
    seqs = [f.seq for f in frames]
    assert seqs == sorted(set(seqs))
    stamps = np.array([f.t_capture_mono_s for f in frames])
    spacing = np.diff(stamps) / np.diff(seqs)
    assert spacing == pytest.approx(1 / 30.0, rel=1e-6)  # the capture grid, whatever the scheduling


async def test_a_slow_consumer_gets_the_latest_frame_not_a_stale_queue() -> None:
    """Reading every 0.2 s at 30 fps: seq jumps by ~6 and each frame is captured after the request."""
    cam = SimDepthCamera(WALL, lambda: pose_at(0.0), camera=SMALL, fps=30.0)
    got = await take(cam, 4, pause_s=0.2)
    for (prev, t_prev_received), (frame, _) in itertools.pairwise(got):
        assert frame.seq - prev.seq >= 5
        assert frame.t_capture_mono_s >= t_prev_received + 0.2 - 1e-3
    assert cam.frames_rendered == 4


async def test_noise_is_reproducible_from_the_seed() -> None:
    noise = parse_config(DepthNoise, {})  # validated, as the configs build it
    runs = []
    for seed in (7, 7, 8):
        cam = SimDepthCamera(WALL, lambda: pose_at(0.0), camera=SMALL, noise=noise, seed=seed)
        runs.append([f.depth_mm for f, _ in await take(cam, 2)])
    assert all(np.array_equal(a, b) for a, b in zip(runs[0], runs[1], strict=False))
    assert not np.array_equal(runs[0][0], runs[2][0])
    assert not np.array_equal(runs[0][0], runs[0][1])  # fresh noise each frame


def test_bad_fps_is_a_clear_error() -> None:
    with pytest.raises(ValueError, match="fps"):
        SimDepthCamera(WALL, lambda: pose_at(0.0), fps=0.0)
