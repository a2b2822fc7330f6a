"""Depth replayed from a folder of 16-bit PNG files (uint16 millimetres, 0 = invalid), in name order."""

from __future__ import annotations

import asyncio
import time
from collections.abc import AsyncIterator
from pathlib import Path

import cv2
import numpy as np

from quadnav_onboard.sources.base import DepthFrame

__all__ = ["ReplayDepthSource", "ReplayError"]


class ReplayError(ValueError):
    """The replay folder or one of its files cannot be used (the message names it)."""


class ReplayDepthSource:
    """:class:`~quadnav_onboard.sources.base.DepthSource` playing ``folder/*.png`` at ``fps``."""

    def __init__(self, folder: str | Path, fps: float = 30.0, loop: bool = True) -> None:
        self.folder = Path(folder)
        self.fps = float(fps)
        self.loop = loop
        self.files: list[Path] = []

    async def __aenter__(self) -> ReplayDepthSource:
        if not self.folder.is_dir():
            raise ReplayError(f"depth.folder {str(self.folder)!r}: not a folder")
        self.files = sorted(self.folder.glob("*.png"))
        if not self.files:
            raise ReplayError(f"depth.folder {str(self.folder)!r}: no .png files")
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    @staticmethod
    def read(path: Path) -> np.ndarray:
        """One PNG as (H, W) uint16 mm; raises ReplayError naming the file otherwise."""
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            raise ReplayError(f"{path}: not a readable PNG")
        if img.dtype != np.uint16 or img.ndim != 2:
            raise ReplayError(f"{path}: need a 16-bit single-channel PNG, got {img.dtype} {img.shape}")
        return img

    async def frames(self) -> AsyncIterator[DepthFrame]:
        period = 1.0 / self.fps
        t_next = time.monotonic()
        seq = 0
        while True:
            for path in self.files:
                img = await asyncio.to_thread(self.read, path)
                t_next += period
                await asyncio.sleep(max(0.0, t_next - time.monotonic()))
                seq += 1
                yield DepthFrame(img, time.monotonic(), seq)
            if not self.loop:
                return
