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
from typing import Annotated, NamedTuple

import cv2
import numba
import numpy as np
import pydantic
from numpy.typing import NDArray

from quadnav_onboard.camera import D435_MAX_RANGE_M, D435_MIN_RANGE_M, INPUT_SIZE_PX
from quadnav_onboard.jit import CAN_CACHE, kernel_array

__all__ = [
    "OUT_SIZE",
    "DepthFrameError",
    "DepthInputs",
    "PreprocessConfig",
    "depth_inputs_mm",
    "nearest_depth_mm",
    "normalize_depth_m",
    "preprocess_depth_mm",
    "preprocess_depth_pair",
    "validate_depth_mm",
]

OUT_SIZE = INPUT_SIZE_PX
"""Side (pixels) of the network's depth input."""

_JIT = {"cache": CAN_CACHE, "nogil": True, "fastmath": False, "error_model": "numpy"}


class DepthFrameError(ValueError):
    """A depth frame that cannot be used (wrong dtype or shape, or nothing valid in it)."""


@dataclass(frozen=True)
class PreprocessConfig:
    """Depth-to-input conversion; defaults are the D435's usable range."""

    # config files: unknown keys are errors, and so are NaN and ±inf (quadnav_onboard.config.CONFIG_DICT)
    __pydantic_config__ = {"extra": "forbid", "allow_inf_nan": False}

    min_range_m: Annotated[float, pydantic.Field(gt=0, le=10)] = D435_MIN_RANGE_M
    """Nearest valid depth (m), in (0, 10] and below ``max_range_m``; nearer readings are clipped up
    to it."""
    max_range_m: Annotated[float, pydantic.Field(gt=0, le=65)] = D435_MAX_RANGE_M
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


@numba.njit(**_JIT)
def _median9(d, i, j, h, w):  # pragma: no cover - compiled
    """Median of the 3x3 neighbourhood of (i, j), edges replicated (as ``cv2.medianBlur``), by a
    19-exchange sorting network."""
    i0, i2 = max(i - 1, 0), min(i + 1, h - 1)
    j0, j2 = max(j - 1, 0), min(j + 1, w - 1)
    p0, p1, p2 = d[i0, j0], d[i0, j], d[i0, j2]
    p3, p4, p5 = d[i, j0], d[i, j], d[i, j2]
    p6, p7, p8 = d[i2, j0], d[i2, j], d[i2, j2]
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p0, p1 = min(p0, p1), max(p0, p1)
    p3, p4 = min(p3, p4), max(p3, p4)
    p6, p7 = min(p6, p7), max(p6, p7)
    p1, p2 = min(p1, p2), max(p1, p2)
    p4, p5 = min(p4, p5), max(p4, p5)
    p7, p8 = min(p7, p8), max(p7, p8)
    p0, p3 = min(p0, p3), max(p0, p3)
    p5, p8 = min(p5, p8), max(p5, p8)
    p4, p7 = min(p4, p7), max(p4, p7)
    p3, p6 = min(p3, p6), max(p3, p6)
    p1, p4 = min(p1, p4), max(p1, p4)
    p2, p5 = min(p2, p5), max(p2, p5)
    p4, p7 = min(p4, p7), max(p4, p7)
    p4, p2 = min(p4, p2), max(p4, p2)
    p6, p4 = min(p6, p4), max(p6, p4)
    p4, p2 = min(p4, p2), max(p4, p2)
    return p4


@numba.njit(**_JIT)
def _cells(frames, min_mm, max_mm, scale, want_mean, want_near, mean_out, near_out, near_at):  # pragma: no cover  # noqa: E501
    """The 32x32 inputs of N depth frames (uint16 mm, (N, H, W), any H, W >= 32).

    Each pixel reads through the range rules: 0 (no return) and beyond ``max_mm`` read as
    ``max_mm``, nearer than ``min_mm`` as ``min_mm``. Cell (i, j) covers rows ``i*H//32`` to
    ``(i+1)*H//32`` and columns likewise. ``mean_out``: the cell's mean (the network input);
    ``near_out``: the least 3x3 median in the cell (the depth safety filter's nearest surface; the
    median drops lone speckles). Both scaled by ``scale`` (1 / max range in mm) and clipped.
    ``near_at``: where in the cell that least median lies, (row, column) of its pixel's centre
    relative to the cell's centre, in input pixels (the first such pixel; 0, 0 where the cell saw
    nothing)."""
    n_f, h, w = frames.shape
    lo = min_mm * scale
    clean = np.empty((h, w), dtype=np.uint16)
    for f in range(n_f):
        for i in range(h):
            for j in range(w):
                v = frames[f, i, j]
                if v == 0 or v > max_mm:
                    v = max_mm
                elif v < min_mm:
                    v = min_mm
                clean[i, j] = v
        for ci in range(OUT_SIZE):
            r0, r1 = (ci * h) // OUT_SIZE, ((ci + 1) * h) // OUT_SIZE
            for cj in range(OUT_SIZE):
                c0, c1 = (cj * w) // OUT_SIZE, ((cj + 1) * w) // OUT_SIZE
                if want_mean:
                    acc = 0.0
                    for i in range(r0, r1):
                        for j in range(c0, c1):
                            acc += clean[i, j]
                    m = acc * scale / ((r1 - r0) * (c1 - c0))
                    mean_out[f, ci, cj] = min(max(m, lo), 1.0)
                if want_near:
                    best = max_mm
                    bi, bj = -1, -1
                    for i in range(r0, r1):
                        for j in range(c0, c1):
                            v = _median9(clean, i, j, h, w)
                            if v < best:
                                best, bi, bj = v, i, j
                    near_out[f, ci, cj] = best * scale
                    if bi < 0:
                        near_at[f, ci, cj, 0] = 0.0
                        near_at[f, ci, cj, 1] = 0.0
                    else:
                        near_at[f, ci, cj, 0] = (bi + 0.5) * OUT_SIZE / h - (ci + 0.5)
                        near_at[f, ci, cj, 1] = (bj + 0.5) * OUT_SIZE / w - (cj + 0.5)


class DepthInputs(NamedTuple):
    """What :func:`depth_inputs_mm` makes of N frames; a field not asked for is None."""

    mean: NDArray[np.float32] | None
    """The network inputs, float32 (N, 32, 32) in [0, 1]: each cell's mean depth / max range."""
    near: NDArray[np.float32] | None
    """The nearest-surface views, float32 (N, 32, 32) in [0, 1]: each cell's least 3x3 median."""
    near_at: NDArray[np.float32] | None
    """Where in its cell each nearest surface was seen, float32 (N, 32, 32, 2): (row, column) of
    the pixel's centre relative to the cell's centre, in input pixels, within about ±0.5. The
    depth safety filter places the surface on that pixel's ray, not the cell's centre ray (on a
    slanted face the two differ by up to the depth across half a cell)."""


def depth_inputs_mm(
    frames_mm: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig(), *, mean: bool = True,
    nearest: bool = False,
) -> DepthInputs:
    """The one preprocessing, training's and flight's: N depth frames (uint16 mm, (N, H, W), 0 =
    no return) -> the network inputs and, with ``nearest``, the nearest-surface views and where in
    each cell they were seen (:class:`DepthInputs`). No validity check (:func:`validate_depth_mm`
    is flight's)."""
    frames = kernel_array(frames_mm, np.uint16)
    if frames.ndim != 3 or frames.shape[1] < OUT_SIZE or frames.shape[2] < OUT_SIZE:
        raise DepthFrameError(f"depth frames must be (N, H, W) with H, W >= {OUT_SIZE}, got {frames.shape}")
    max_mm = int(np.floor(cfg.max_range_m * 1000.0))
    min_mm = min(int(np.ceil(cfg.min_range_m * 1000.0)), max_mm)
    n = frames.shape[0]
    n_near = n if nearest else 0
    mean_out = np.empty((n if mean else 0, OUT_SIZE, OUT_SIZE), dtype=np.float32)
    near_out = np.empty((n_near, OUT_SIZE, OUT_SIZE), dtype=np.float32)
    near_at = np.empty((n_near, OUT_SIZE, OUT_SIZE, 2), dtype=np.float32)
    _cells(frames, min_mm, max_mm, 1.0 / (cfg.max_range_m * 1000.0), mean, nearest, mean_out, near_out,
           near_at)
    if not nearest:
        return DepthInputs(mean_out if mean else None, None, None)
    return DepthInputs(mean_out if mean else None, near_out, near_at)


def preprocess_depth_mm(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> NDArray[np.float32]:
    """Raw D435 depth (uint16 mm, shape (H, W), 0 = invalid) -> network input float32 (32, 32).

    Raises :class:`DepthFrameError` for a wrong dtype or shape, or when fewer than
    ``min_valid_fraction`` of the pixels hold a valid reading.
    """
    _checked(frame, cfg)
    return depth_inputs_mm(np.asarray(frame)[None], cfg).mean[0]  # type: ignore[index]


def nearest_depth_mm(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> NDArray[np.float32]:
    """Raw D435 depth -> the nearest surface in each of the 32x32 cells, float32 in [0, 1] like the
    network input (the depth safety filter's ``depth_pooling: min``).

    The cells are bands of H/32 rows and W/32 columns (rounded down). A 3x3 median first removes
    lone speckles: a surface must cover a few pixels to count. Raises :class:`DepthFrameError` as
    :func:`preprocess_depth_mm` does.
    """
    _checked(frame, cfg)
    return depth_inputs_mm(np.asarray(frame)[None], cfg, mean=False, nearest=True).near[0]  # type: ignore[index]


def preprocess_depth_pair(
    frame: NDArray[np.uint16], cfg: PreprocessConfig = PreprocessConfig()
) -> tuple[NDArray[np.float32], NDArray[np.float32], NDArray[np.float32]]:
    """Both views of one frame, checked once: (:func:`preprocess_depth_mm`,
    :func:`nearest_depth_mm`, where in each cell the nearest surface was seen (32, 32, 2), as
    :attr:`DepthInputs.near_at`)."""
    _checked(frame, cfg)
    out = depth_inputs_mm(np.asarray(frame)[None], cfg, nearest=True)
    return out.mean[0], out.near[0], out.near_at[0]  # type: ignore[index]
