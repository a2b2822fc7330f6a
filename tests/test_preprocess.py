"""Depth preprocessing: raw D435 frame -> 32x32 network input."""

import cv2
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from quadnav_onboard.preprocess import (
    DepthFrameError,
    PreprocessConfig,
    area_downsample,
    nearest_depth_mm,
    normalize_depth_m,
    preprocess_depth_mm,
    preprocess_depth_pair,
    validate_depth_mm,
)

CFG = PreprocessConfig()


def test_uniform_depth_maps_to_depth_over_max_range():
    """A wall at 5 m everywhere becomes 0.5 everywhere."""
    out = preprocess_depth_mm(np.full((480, 848), 5000, np.uint16))
    assert out.shape == (32, 32) and out.dtype == np.float32
    np.testing.assert_allclose(out, 0.5, atol=1e-6)


def test_invalid_pixels_read_as_far_not_near():
    """0 (no data) and beyond-range pixels become max range (1.0), not zero."""
    frame = np.full((240, 424), 2000, np.uint16)
    frame[:, :212] = 0
    frame[:10, 212:] = 65000
    out = normalize_depth_m(frame.astype(np.float32) / 1000.0)
    assert out[:, :212].min() == 1.0
    assert out[:10, 212:].min() == 1.0
    assert np.allclose(out[20:, 212:], 0.2)


def test_near_readings_are_clipped_to_min_range():
    out = normalize_depth_m(np.array([0.05, 0.2, 1.0], np.float32))
    np.testing.assert_allclose(out, [0.02, 0.02, 0.1], rtol=1e-6)


def test_each_cell_is_the_mean_of_its_band_of_pixels():
    """Cell (i, j) is the mean of rows i*H//32..(i+1)*H//32 and columns likewise, after invalid
    handling; where 32 divides the frame that is exactly OpenCV's INTER_AREA."""
    rng = np.random.default_rng(0)
    frame = rng.integers(300, 9000, size=(480, 848), dtype=np.uint16)
    rows, cols = (np.arange(33) * 480) // 32, (np.arange(33) * 848) // 32
    expected = np.array([[frame[rows[i]:rows[i + 1], cols[j]:cols[j + 1]].mean() / 10000.0
                          for j in range(32)] for i in range(32)])
    np.testing.assert_allclose(preprocess_depth_mm(frame), expected, atol=1e-6)
    square = rng.integers(300, 9000, size=(256, 256), dtype=np.uint16)
    area = cv2.resize(square.astype(np.float32) / 10000.0, (32, 32), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(preprocess_depth_mm(square), area, atol=1e-6)


def test_left_obstacle_shows_on_the_left():
    """A near object in the left third of the image lowers the left columns of the input."""
    frame = np.full((240, 424), 8000, np.uint16)
    frame[:, :141] = 1000
    out = preprocess_depth_mm(frame)
    assert out[:, :10].mean() < 0.2 and out[:, -10:].mean() > 0.7


def test_batched_block_mean_equals_opencv_area():
    """The vectorised batch path equals cv2 INTER_AREA frame by frame."""
    rng = np.random.default_rng(2)
    batch = rng.random((3, 64, 64), dtype=np.float32)
    fast = area_downsample(batch)
    slow = np.stack([cv2.resize(b, (32, 32), interpolation=cv2.INTER_AREA) for b in batch])
    np.testing.assert_allclose(fast, slow, atol=1e-6)


@given(st.integers(32, 200), st.integers(32, 200))
def test_any_resolution_gives_32x32_in_range(h, w):
    frame = np.random.default_rng(h * w).integers(0, 20000, size=(h, w), dtype=np.uint16)
    frame[0, 0] = 1500  # at least some valid pixels
    frame[:, : max(1, w // 2)] = 3000
    out = preprocess_depth_mm(frame)
    assert out.shape == (32, 32)
    assert (out >= CFG.min_range_m / CFG.max_range_m - 1e-6).all() and (out <= 1.0).all()


@pytest.mark.parametrize(
    ("frame", "match"),
    [
        (np.full((240, 424), 2.0, np.float32), "uint16"),
        (np.full((240, 424, 3), 2000, np.uint16), "2-D"),
        (np.full((16, 16), 2000, np.uint16), "at least 32x32"),
        (np.zeros((240, 424), np.uint16), "valid pixels"),
    ],
)
def test_unusable_frames_are_rejected(frame, match):
    """Wrong dtype, wrong shape, too small or all invalid: a clear DepthFrameError, from the
    check alone (what the daemon runs on frames it does not prepare) as from preprocessing."""
    with pytest.raises(DepthFrameError, match=match):
        preprocess_depth_mm(frame)
    with pytest.raises(DepthFrameError, match=match):
        validate_depth_mm(frame)


@given(st.floats(0.0, 0.2), st.integers(0, 2**32 - 1))
def test_the_check_alone_accepts_exactly_what_preprocessing_accepts(invalid_share, seed):
    """Frames with a share of invalid pixels around the limit: the check raises iff preprocessing does."""
    rng = np.random.default_rng(seed)
    frame = rng.integers(200, 12_000, (60, 80)).astype(np.uint16)
    frame[rng.random(frame.shape) < 1.0 - invalid_share] = 0  # mostly invalid: near min_valid_fraction
    outcomes = []
    for fn in (preprocess_depth_mm, validate_depth_mm):
        try:
            fn(frame, CFG)
            outcomes.append("ok")
        except DepthFrameError as exc:
            outcomes.append(str(exc))
    assert outcomes[0] == outcomes[1]


def test_nearest_view_keeps_a_thin_pole_and_ignores_a_lone_speckle():
    """The shield's view: a pole 3 px wide at 1.5 m keeps its depth in its cells (the area average
    blends it); one speckle pixel at 0.3 m is not an obstacle; holes read as far."""
    frame = np.full((240, 424), 6000, np.uint16)
    frame[:, 200:203] = 1500
    frame[50, 50] = 300
    frame[200:, :100] = 0
    near, mean = nearest_depth_mm(frame), preprocess_depth_mm(frame)
    assert near.shape == (32, 32) and near.dtype == np.float32
    col = 200 * 32 // 424
    np.testing.assert_allclose(near[:, col], 0.15, atol=1e-6)
    assert mean[:, col].min() > 0.4
    assert near.min() == pytest.approx(0.15)  # the speckle did not count
    np.testing.assert_allclose(np.delete(near, col, axis=1)[:26, :], 0.6, atol=1e-6)
    speckle = (50 * 32 // 240, 50 * 32 // 424)
    assert near[speckle] > mean[speckle]  # the average counted it
    mean[speckle] = near[speckle]
    assert np.all(near <= mean + 1e-5)  # elsewhere nothing is farther than the average
    pair = preprocess_depth_pair(frame)
    np.testing.assert_array_equal(pair[0], preprocess_depth_mm(frame))
    np.testing.assert_array_equal(pair[1], near)
    assert pair[2].shape == (32, 32, 2) and np.all(np.abs(pair[2]) < 0.55)  # whole-pixel cells: 0.52


def test_the_nearest_view_says_where_in_its_cell_it_saw_the_surface():
    """A 4x4-pixel patch at 1 m in one cell of a 240 x 424 frame (cells 7-8 x 13-14 pixels): the
    first pixel whose 3x3 median is the patch's depth is (38, 141); ``near_at`` is that pixel's
    centre, in input pixels, from the cell's centre. Cells that saw nothing say (0, 0)."""
    frame = np.full((240, 424), 6000, np.uint16)
    frame[38:42, 140:144] = 1000
    frame[200:, :] = 0
    _, near, at = preprocess_depth_pair(frame)
    ci, cj = 38 * 32 // 240, 141 * 32 // 424
    assert (ci, cj) == (5, 10) and near[ci, cj] == pytest.approx(0.1)
    np.testing.assert_allclose(at[ci, cj], [38.5 * 32 / 240 - 5.5, 141.5 * 32 / 424 - 10.5], atol=1e-6)
    np.testing.assert_array_equal(at[31, 0], [0.0, 0.0])  # no return there
    assert np.all(np.abs(at) < 0.55)


def test_nearest_view_refuses_what_the_network_input_refuses():
    with pytest.raises(DepthFrameError, match="uint16"):
        nearest_depth_mm(np.zeros((240, 424), np.float32))
    with pytest.raises(DepthFrameError, match="valid pixels"):
        nearest_depth_mm(np.zeros((240, 424), np.uint16))
