"""D435 over UVC (kernel uvcvideo, no librealsense): raw Z16 depth through the daemon's own source.

QUADNAV_D435_DEVICE=auto (find the depth node, as ``depth.device: auto`` does) or the node itself,
e.g. /dev/video2 (`v4l2-ctl --list-devices`). Point the camera at a wall or a person 0.5-5 m away.
"""

from __future__ import annotations

import asyncio
import time

import numpy as np
import pytest
from conftest import require_env

from quadnav_onboard.preprocess import PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.sources.uvc import (
    AUTO_DEVICE,
    UvcDepthSource,
    V4l2Mode,
    find_depth_node,
    v4l2_capture_formats,
)

WIDTH, HEIGHT, FPS = 424, 240, 30.0


@pytest.fixture
def device() -> str:
    return require_env("QUADNAV_D435_DEVICE", "D435 depth node (or 'auto')")


def test_depth_node_is_found_by_name_and_format(device: str) -> None:
    """Exactly one V4L2 node is named RealSense and offers Z16 (the depth node), and it is readable."""
    node = find_depth_node()
    print(f"depth node: {node}, formats {v4l2_capture_formats(node)}")
    if device != AUTO_DEVICE:
        assert node == device, f"QUADNAV_D435_DEVICE={device} but the depth node found is {node}"


async def test_mode_is_granted_and_frames_are_millimetres_at_rate(device: str) -> None:
    """Z16 424x240 @ 30 Hz is granted as asked; 60 frames arrive at >= 25 Hz, stamped by the driver
    less than 100 ms before they reach us, plausible depth in mm, preprocessed to a 32x32 input."""
    async with UvcDepthSource(device, WIDTH, HEIGHT, FPS) as src:
        assert src.granted == V4l2Mode("Z16 ", WIDTH, HEIGHT, FPS)
        frames, ages_s, t0 = [], [], time.monotonic()
        stream = src.frames()
        while len(frames) < 60:
            f = await asyncio.wait_for(anext(stream), 2.0)
            ages_s.append(time.monotonic() - f.t_capture_mono_s)
            frames.append(f)
        rate_hz = 60 / (time.monotonic() - t0)
        print(
            f"D435 {src.granted} on {src.opened_device}: {rate_hz:.1f} Hz, timestamps {src.timestamps}, "
            f"age p50 {1e3 * np.median(ages_s):.1f} ms max {1e3 * max(ages_s):.1f} ms"
        )
        assert rate_hz >= 25.0
        assert src.timestamps == "driver", "no usable V4L2 buffer timestamps: capture time = arrival"
        assert min(ages_s) >= 0.0 and max(ages_s) < 0.1
    depth_mm = frames[-1].depth_mm
    valid = depth_mm > 0
    assert valid.mean() > 0.3, f"only {valid.mean():.0%} valid pixels"
    assert 200 < np.median(depth_mm[valid]) < 10_000, "median depth outside 0.2-10 m: units wrong?"
    net_input = preprocess_depth_mm(depth_mm, PreprocessConfig())
    assert net_input.shape == (32, 32) and 0.0 <= net_input.min() <= net_input.max() <= 1.0
