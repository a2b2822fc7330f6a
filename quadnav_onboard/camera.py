"""The depth camera's fixed numbers, defined once: the D435's field of view and range, and the
side of the network's depth input. The sim's camera model, the preprocessing, the depth safety
filter and the flight record all read them from here."""

from __future__ import annotations

__all__ = ["D435_HFOV_DEG", "D435_MAX_RANGE_M", "D435_MIN_RANGE_M", "D435_VFOV_DEG", "INPUT_SIZE_PX"]

D435_HFOV_DEG = 87.0
"""Horizontal field of view (deg) of a RealSense D435's depth stream."""
D435_VFOV_DEG = 58.0
"""Vertical field of view (deg) of a RealSense D435's depth stream."""
D435_MIN_RANGE_M = 0.2
"""Nearest depth (m) a D435 reports (its min-Z at the default resolution); nearer reads 0."""
D435_MAX_RANGE_M = 10.0
"""Farthest depth (m) this project uses from a D435; also the network input's far end."""
INPUT_SIZE_PX = 32
"""Side (pixels) of the network's square depth input."""
