"""Depth preprocessing: one function from a raw depth frame to the network's 32x32 input.

A D435 delivers uint16 depth in millimetres with 0 for "no data". The network sees a float32
32x32 image in [0, 1]: depth in metres, clipped to [min_range_m, max_range_m], divided by
max_range_m. Invalid pixels (0, NaN, beyond max range) read as max range ("nothing seen");
pixels nearer than min range read as min range. Downsampling is area averaging
(``cv2.INTER_AREA``), applied after invalid handling so holes do not pull the average to zero.

The same functions serve the simulator (batched float depth) and the vehicle (uint16 frames):
what is trained is exactly what flies. :func:`nearest_depth_mm` is the depth safety filter's view
of the same frame (:mod:`quadnav_onboard.shield`): the nearest surface in each cell instead of the
average, after a 3x3 median so that a lone speckle is not an obstacle.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Annotated

import cv2
import numpy as np
import pydantic
from numpy.typing import NDArray

__all__ = [
    "DepthFrameError",
    "PreprocessConfig",
    "nearest_depth_mm",
    "normalize_depth_m",
    "preprocess_depth_mm",
    "preprocess_depth_pair",
    "validate_depth_mm",
]

OUT_SIZE = 32


class DepthFrameError(ValueError):
    """A depth frame that cannot be used (wrong dtype or shape, or nothing valid in it)."""


@dataclass(frozen=True)
class PreprocessConfig:
    """Depth-to-input conversion; defaults are the D435's usable range."""

    # config files: unknown keys are errors, and so are NaN and ±inf (quadnav_onboard.config.CONFIG_DICT)
    __pydantic_config__ = {"extra": "forbid", "allow_inf_nan": False}

    min_range_m: Annotated[float, pydantic.Field(gt=0, le=10)] = 0.2
    """Nearest valid depth (m), in (0, 10] and below ``max_range_m``; nearer readings are clipped up
    to it."""
    max_range_m: Annotated[float, pydantic.Field(gt=0, le=65)] = 10.0
    """Farthest depth (m), in (0, 65] (uint16 millimetres end at 65.5 m); farther and invalid
    readings become this, i.e. 1.0 after scaling."""
    min_valid_fraction: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.05
    """A frame with fewer valid pixels than this fraction, in (0, 1], is rejected as unusable (0
    would accept a blocked camera's blank frame as "nothing seen")."""

    def __post_init__(self) -> None:
        if not self.min_range_m < self.max_range_m:
            raise ValueError(f"min_range_m {self.min_range_m} must be below max_range_m {self.max_range_m}")


def normalize_depth_m(
    depth_m: NDArray[np.floating], cfg: PreprocessConfig = PreprocessConfig()
) -> NDArray[np.float32]:
    """Depth in metres (any shape; 0, NaN, Inf or > max = invalid) -> float32 in [min/max, 1]."""
    d = np.asarray(depth_m, dtype=np.float32)
    invalid = ~np.isfinite(d) | (d <= 0.0) | (d > cfg.max_range_m)
    d = np.where(invalid, cfg.max_range_m, np.clip(d, cfg.min_range_m, cfg.max_range_m))
    return (d / cfg.max_range_m).astype(np.float32)


def area_downsample(img: NDArray[np.float32], size: int = OUT_SIZE) -> NDArray[np.float32]:
    """Area-average an (H, W) or (N, H, W) float32 image to (…, size, size)."""
    if img.ndim == 2:
        return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    n, h, w = img.shape
    if h % size == 0 and w % size == 0:  # exact block mean: identical to INTER_AREA, vectorised
        return img.reshape(n, size, h // size, size, w // size).mean(axis=(2, 4), dtype=np.float32)
    return np.stack([cv2.resize(f, (size, size), interpolation=cv2.INTER_AREA) for f in img])


def _checked(frame: NDArray[np.uint16], cfg: PreprocessConfig) -> tuple[NDArray, NDArray[np.bool_], int]:
    """The frame as an array, its valid-pixel mask and the range's far end (mm), after the checks
    every use of a frame shares (dtype, shape, enough valid pixels)."""
    arr = np.asarray(frame)
    if arr.dtype != np.uint16:
        raise DepthFrameError(f"depth frame must be uint16 millimetres, got dtype {arr.dtype}")
    if arr.ndim != 2 or arr.shape[0] < OUT_SIZE or arr.shape[1] < OUT_SIZE:
        raise DepthFrameError(
            f"depth frame must be 2-D and at least {OUT_SIZE}x{OUT_SIZE}, got shape {arr.shape}"
        )
    max_mm = int(np.floor(cfg.max_range_m * 1000.0))
    valid = (arr - np.uint16(1)) < np.uint16(max_mm)  # uint16 wrap-around: 0 -> 65535, invalid
    frac = np.count_nonzero(valid) / valid.size
    if frac < cfg.min_valid_fraction:
        raise DepthFrameError(
            f"depth frame has {frac:.1%} valid pixels (< {cfg.min_valid_fraction:.0%}): "
            "camera blocked or broken?"
        )
    return arr, valid, max_mm


def validate_depth_mm(frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()) -> None:
    """Raise :class:`DepthFrameError` exactly when :func:`preprocess_depth_mm` would, without
    preprocessing (a fraction of its cost: the daemon checks every frame it does not prepare)."""
    _checked(frame, cfg)


def _clean_mm(frame: NDArray[np.uint16], cfg: PreprocessConfig) -> NDArray[np.uint16]:
    """A checked frame with the range rules applied in the integer domain: 0 and > max read as
    max, < min as min (the same mapping as :func:`normalize_depth_m`, in a few passes: this runs on
    every frame in flight)."""
    arr, valid, max_mm = _checked(frame, cfg)
    min_mm = min(int(np.ceil(cfg.min_range_m * 1000.0)), max_mm)
    depth_mm = np.where(valid, arr, np.uint16(max_mm))
    np.maximum(depth_mm, np.uint16(min_mm), out=depth_mm)
    return depth_mm


def _area_input(depth_mm: NDArray[np.uint16], cfg: PreprocessConfig) -> NDArray[np.float32]:
    out = area_downsample(depth_mm.astype(np.float32))
    out *= np.float32(1.0 / (cfg.max_range_m * 1000.0))
    return np.clip(out, cfg.min_range_m / cfg.max_range_m, 1.0, out=out)  # float rounding of the mean


def _nearest_input(depth_mm: NDArray[np.uint16], cfg: PreprocessConfig) -> NDArray[np.float32]:
    depth_mm = cv2.medianBlur(depth_mm, 3)
    h, w = depth_mm.shape
    # columns first, along contiguous rows (about 10x faster than rows first)
    cols = np.minimum.reduceat(depth_mm, (np.arange(OUT_SIZE) * w) // OUT_SIZE, axis=1)
    cells = np.minimum.reduceat(cols, (np.arange(OUT_SIZE) * h) // OUT_SIZE, axis=0)
    return cells.astype(np.float32) * np.float32(1.0 / (cfg.max_range_m * 1000.0))


def preprocess_depth_mm(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> NDArray[np.float32]:
    """Raw D435 depth (uint16 mm, shape (H, W), 0 = invalid) -> network input float32 (32, 32).

    Raises :class:`DepthFrameError` for a wrong dtype or shape, or when fewer than
    ``min_valid_fraction`` of the pixels hold a valid reading.
    """
    return _area_input(_clean_mm(frame, cfg), cfg)


def nearest_depth_mm(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> NDArray[np.float32]:
    """Raw D435 depth -> the nearest surface in each of the 32x32 cells, float32 in [0, 1] like the
    network input (the depth safety filter's ``depth_pooling: min``).

    The cells are bands of H/32 rows and W/32 columns (rounded down). A 3x3 median first removes
    lone speckles: a surface must cover a few pixels to count. Raises :class:`DepthFrameError` as
    :func:`preprocess_depth_mm` does.
    """
    return _nearest_input(_clean_mm(frame, cfg), cfg)


def preprocess_depth_pair(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
    """Both views of one frame, checked once: (:func:`preprocess_depth_mm`,
    :func:`nearest_depth_mm`)."""
    depth_mm = _clean_mm(frame, cfg)
    return _area_input(depth_mm, cfg), _nearest_input(depth_mm, cfg)
