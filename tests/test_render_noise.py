"""The D435-like noise model: seeded, reproducible, and shaped like a stereo camera's errors."""

from __future__ import annotations

import numpy as np

from quadnav_onboard.frames import quat_from_yaw
from sim_harness.noise import DepthNoise, apply_depth_noise
from sim_harness.render import D435_424x240, render_frame_mm
from sim_harness.world import load_world, paper_world_path


def test_same_seed_same_noise_bit_for_bit() -> None:
    """Two generators with the same seed give identical noisy frames; another seed differs."""
    w = load_world(paper_world_path(8))
    pose = (np.array([3.0, 0.0, 2.0]), quat_from_yaw(0.1))
    a = render_frame_mm(w, *pose, D435_424x240, DepthNoise(), np.random.default_rng(7))
    b = render_frame_mm(w, *pose, D435_424x240, DepthNoise(), np.random.default_rng(7))
    c = render_frame_mm(w, *pose, D435_424x240, DepthNoise(), np.random.default_rng(8))
    clean = render_frame_mm(w, *pose, D435_424x240)
    np.testing.assert_array_equal(a, b)
    assert (a != c).any() and (a != clean).any()


def test_noise_grows_with_depth_squared() -> None:
    """The spread at 8 m is ~16x the spread at 2 m (sigma = k z^2)."""
    cfg = DepthNoise(edge_invalid_prob=0.0, dropout_prob=0.0)
    rng = np.random.default_rng(0)
    near = apply_depth_noise(np.full((200, 200), 2.0), cfg, rng)
    far = apply_depth_noise(np.full((200, 200), 8.0), cfg, rng)
    assert abs(near.std() - cfg.sigma_coeff_per_m * 4) < 0.1 * cfg.sigma_coeff_per_m * 4
    assert 14.0 < far.std() / near.std() < 18.0


def test_invalid_stays_invalid_edges_and_dropout_make_holes() -> None:
    """Zeros stay zero; pixels at a depth step are dropped more often than the flat dropout rate."""
    depth = np.full((100, 100), 3.0, dtype=np.float32)
    depth[:, 50:] = 6.0  # a vertical depth edge between columns 49 and 50
    depth[:10] = 0.0
    cfg = DepthNoise(sigma_coeff_per_m=0.0, edge_invalid_prob=0.9, dropout_prob=0.02)
    out = apply_depth_noise(depth, cfg, np.random.default_rng(1))
    assert (out[:10] == 0).all()
    edge_drop = (out[10:, 49:51] == 0).mean()
    flat_drop = (out[10:, :40] == 0).mean()
    assert edge_drop > 0.8 and 0.005 < flat_drop < 0.05
    np.testing.assert_array_equal(out[10:, :40][out[10:, :40] > 0], 3.0)


def test_noise_never_reports_past_range() -> None:
    """Noisy readings beyond max range are dropped to 0."""
    out = apply_depth_noise(np.full((100, 100), 9.9), DepthNoise(sigma_coeff_per_m=0.01, dropout_prob=0.0),
                            np.random.default_rng(2), max_range_m=10.0)
    assert out.max() <= 10.0 and (out == 0).any()
