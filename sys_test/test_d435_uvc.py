"""D435 over UVC (kernel uvcvideo, no librealsense): raw Z16 depth through OpenCV's V4L2 backend.

QUADNAV_D435_DEVICE=/dev/video2 (the depth node; `v4l2-ctl --list-devices`). Point the camera at a
wall or a person 0.5-5 m away.
"""

from __future__ import annotations

import time

import cv2
import numpy as np
import pytest
from conftest import require_env

from quadnav_onboard.preprocess import PreprocessConfig, preprocess_depth_mm

WIDTH, HEIGHT, FPS = 424, 240, 30


@pytest.fixture
def capture() -> cv2.VideoCapture:
    device = require_env("QUADNAV_D435_DEVICE", "D435 depth node")
    cap = cv2.VideoCapture(int(device) if device.isdigit() else device, cv2.CAP_V4L2)
    assert cap.isOpened(), f"{device}: cannot open with CAP_V4L2 (group quadnav? udev rule?)"
    cap.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc("Z", "1", "6", " "))
    cap.set(cv2.CAP_PROP_FRAME_WIDTH, WIDTH)
    cap.set(cv2.CAP_PROP_FRAME_HEIGHT, HEIGHT)
    cap.set(cv2.CAP_PROP_FPS, FPS)
    cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
    yield cap
    cap.release()


def _as_depth_mm(frame: np.ndarray) -> np.ndarray:
    """OpenCV hands Z16 over as uint16 (H, W), or as raw bytes on older builds."""
    if frame.dtype == np.uint16:
        return frame.reshape(HEIGHT, WIDTH)
    return np.frombuffer(frame.tobytes(), dtype="<u2").reshape(HEIGHT, WIDTH)


def test_device_negotiates_z16_at_424x240(capture: cv2.VideoCapture) -> None:
    """The driver accepts the Z16 format at 424x240 (the depth node, not the RGB or IR node)."""
    fourcc = int(capture.get(cv2.CAP_PROP_FOURCC))
    assert fourcc.to_bytes(4, "little") == b"Z16 ", f"got fourcc {fourcc.to_bytes(4, 'little')!r}"
    assert int(capture.get(cv2.CAP_PROP_FRAME_WIDTH)) == WIDTH
    assert int(capture.get(cv2.CAP_PROP_FRAME_HEIGHT)) == HEIGHT


def test_frames_are_millimetres_and_arrive_at_rate(capture: cv2.VideoCapture) -> None:
    """60 frames arrive at >= 25 Hz, each plausible depth in mm, and preprocess to a 32x32 input."""
    frames, t0 = [], time.monotonic()
    while len(frames) < 60:
        ok, frame = capture.read()
        assert ok, "read failed"
        frames.append(_as_depth_mm(frame))
    rate_hz = 60 / (time.monotonic() - t0)
    print(f"D435 Z16 {WIDTH}x{HEIGHT}: {rate_hz:.1f} Hz")
    assert rate_hz >= 25.0
    depth_mm = frames[-1]
    valid = depth_mm > 0
    assert valid.mean() > 0.3, f"only {valid.mean():.0%} valid pixels"
    assert 200 < np.median(depth_mm[valid]) < 10_000, "median depth outside 0.2-10 m: units wrong?"
    net_input = preprocess_depth_mm(depth_mm, PreprocessConfig())
    assert net_input.shape == (32, 32) and 0.0 <= net_input.min() <= net_input.max() <= 1.0
