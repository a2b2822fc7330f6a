"""numba settings shared by every compiled kernel: the depth safety filter's, and the sim
harness's render and collision kernels."""

from __future__ import annotations

import numba

__all__ = ["CAN_CACHE"]


def _probe() -> None:  # pragma: no cover - only ever decorated, never called
    """A function to ask numba whether it can cache the kernels of this package."""


def _can_cache() -> bool:
    """Whether numba has a writable cache location for this package: its ``__pycache__``,
    ``NUMBA_CACHE_DIR`` or the user's cache directory. A read-only install run by a user without
    a writable home has none; the kernels then compile once per process instead of failing."""
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError:
        return False
    return True


CAN_CACHE: bool = _can_cache()
"""Compile kernels with ``cache=True`` (False: compile in every process)."""
