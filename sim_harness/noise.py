"""A D435-like depth noise model (optional; the renderer is noise-free by default).

What a stereo depth camera such as the D435 does to a depth image, in the order applied:

* **axial noise** growing with the square of depth: ``sigma_m = sigma_coeff_per_m * z**2``
  (stereo depth error ∝ z² · subpixel error / (focal length · baseline); 0.0036 /m is the D435
  at 848x480 with 0.08 px subpixel error and a 50 mm baseline, i.e. 4 mm at 1 m, 0.36 m at 10 m);
* **invalid pixels at depth edges**: where a 4-neighbour differs by more than
  ``edge_rel_threshold`` of the pixel's depth (occlusion at silhouettes), with probability
  ``edge_invalid_prob``;
* **random dropout** of ``dropout_prob`` of the pixels (texture-less or specular patches);
* **past range**: readings beyond ``max_range_m`` are dropped (0).

Pure: a function of the image, the config and the ``numpy.random.Generator`` passed in.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Annotated

import numpy as np
import pydantic
from numpy.typing import NDArray

__all__ = ["DepthNoise", "apply_depth_noise", "noise_at_width"]


@dataclass(frozen=True)
class DepthNoise:
    """Parameters of the D435-like noise model; defaults are a D435 at 848x480 indoors."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    sigma_coeff_per_m: Annotated[float, pydantic.Field(ge=0)] = 0.0036
    """Axial noise: standard deviation (m) = this (1/m) times depth² (m²)."""
    edge_rel_threshold: Annotated[float, pydantic.Field(gt=0)] = 0.1
    """A pixel whose depth differs from a valid 4-neighbour by more than this fraction is an edge."""
    edge_invalid_prob: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.5
    """Probability that an edge pixel reads 0."""
    dropout_prob: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.01
    """Probability that any pixel reads 0."""


def _edge_mask(depth_m: NDArray[np.float32], rel: float) -> NDArray[np.bool_]:
    """Pixels (valid) with a valid 4-neighbour differing by more than ``rel`` of their depth; (..., H, W)."""
    valid = depth_m > 0
    edge = np.zeros(depth_m.shape, dtype=bool)
    for axis in (-1, -2):
        d = np.diff(depth_m, axis=axis)
        both = valid[..., 1:, :] & valid[..., :-1, :] if axis == -2 else valid[..., 1:] & valid[..., :-1]
        lo = (
            np.minimum(depth_m[..., 1:, :], depth_m[..., :-1, :])
            if axis == -2
            else np.minimum(depth_m[..., 1:], depth_m[..., :-1])
        )
        jump = both & (np.abs(d) > rel * lo)
        if axis == -1:
            edge[..., 1:] |= jump
            edge[..., :-1] |= jump
        else:
            edge[..., 1:, :] |= jump
            edge[..., :-1, :] |= jump
    return edge & valid


def apply_depth_noise(
    depth_m: NDArray[np.floating], cfg: DepthNoise, rng: np.random.Generator, max_range_m: float = 10.0
) -> NDArray[np.float32]:
    """Noisy copy of a depth image (m, shape (..., H, W), 0 = invalid) -> float32, 0 = invalid.

    Invalid input pixels stay invalid. The same ``rng`` state gives the same result, bit for bit.
    """
    d = np.asarray(depth_m, dtype=np.float32)
    valid = d > 0
    edge = _edge_mask(d, cfg.edge_rel_threshold)
    noisy = d + rng.standard_normal(d.shape, dtype=np.float32) * np.float32(cfg.sigma_coeff_per_m) * d * d
    drop = ~valid | (noisy <= 0) | (noisy > max_range_m)
    drop |= edge & (rng.random(d.shape, dtype=np.float32) < cfg.edge_invalid_prob)
    drop |= rng.random(d.shape, dtype=np.float32) < cfg.dropout_prob
    return np.where(drop, np.float32(0.0), noisy).astype(np.float32)


def noise_at_width(cfg: DepthNoise, width_px: int, camera_width_px: int = 424) -> DepthNoise:
    """``cfg`` (written for a camera ``camera_width_px`` wide) for frames ``width_px`` wide of the
    same field of view (the sim's 64 px training frames). An edge invalidates a band about one
    camera pixel wide; a coarser frame's pixel spans ``camera_width_px / width_px`` of them, so its
    edge pixels are dropped with proportionally lower probability: the same expected share of each
    input cell lost at silhouettes. Axial noise and random dropout are per pixel and stay."""
    if not 0 < width_px <= camera_width_px:
        raise ValueError(f"need 0 < width_px <= camera_width_px, got {width_px} and {camera_width_px}")
    return replace(cfg, edge_invalid_prob=cfg.edge_invalid_prob * width_px / camera_width_px)
