"""Latest-value holders and bounded latency statistics (no unbounded queues anywhere)."""

from __future__ import annotations

import asyncio
import math
from collections import deque
from collections.abc import Iterable
from typing import Generic, TypeVar

import numpy as np

__all__ = ["LatencyStats", "Latest"]

T = TypeVar("T")


class Latest(Generic[T]):
    """Holds the newest value only (latest wins); ``wait_newer`` waits for a value after ``seq``."""

    def __init__(self) -> None:
        self.value: T | None = None
        self.seq = 0
        self._cond = asyncio.Event()

    def set(self, value: T) -> None:
        self.value = value
        self.seq += 1
        self._cond.set()
        self._cond = asyncio.Event()

    async def wait_newer(self, seq: int) -> T:
        """Return the value once ``self.seq > seq`` (callers wrap this in ``asyncio.timeout``)."""
        while self.seq <= seq:
            await self._cond.wait()
        assert self.value is not None
        return self.value


class LatencyStats:
    """A bounded window of durations (s) with percentiles in ms."""

    def __init__(self, maxlen: int = 20_000) -> None:
        self._values: deque[float] = deque(maxlen=maxlen)

    def add(self, seconds: float) -> None:
        self._values.append(float(seconds))

    def extend(self, values: Iterable[float]) -> None:
        self._values.extend(float(v) for v in values)

    def __len__(self) -> int:
        return len(self._values)

    def percentile_ms(self, q: float) -> float:
        """The q-th percentile (0..100) in ms; NaN when empty."""
        if not self._values:
            return math.nan
        return float(np.percentile(np.fromiter(self._values, float), q) * 1e3)

    def summary(self) -> dict[str, float]:
        """{"n", "p50_ms", "p99_ms", "max_ms"} (NaN when empty)."""
        return {
            "n": float(len(self._values)),
            "p50_ms": self.percentile_ms(50),
            "p99_ms": self.percentile_ms(99),
            "max_ms": self.percentile_ms(100),
        }
