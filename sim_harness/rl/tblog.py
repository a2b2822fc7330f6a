"""TensorBoard event files of a training run (``RUN_DIR/tb``), the RL field's convention.

Per finished episode: ``episode/reward``, ``episode/length``, ``episode/progress_m``, the running
outcome rates over the last ``window`` episodes (``outcome/goal``, ``outcome/crash``,
``outcome/deviation``, ``outcome/timeout``), ``schedule/epsilon``, ``schedule/gamma`` and
``train/loss``; per evaluation, ``eval/<key>`` for each score. The x axis is the episode count.
The run directory keeps its metrics CSV/JSON; these files only add the TensorBoard view.

Needs the ``tensorboard`` package (``pip install "quadnav[tensorboard]"``): torch's
``SummaryWriter`` imports it. Without it :func:`open_tensorboard` returns None and says so once.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import structlog

from sim_harness.env import OUTCOMES

__all__ = ["TensorBoardLog", "open_tensorboard", "tensorboard_available"]

log = structlog.get_logger(__name__)


def tensorboard_available() -> bool:
    """Whether torch.utils.tensorboard can be imported (it needs the tensorboard package)."""
    try:
        import torch.utils.tensorboard  # noqa: F401
    except ImportError:
        return False
    return True


class TensorBoardLog:
    """Writes one run's scalars; ``writer`` is a ``torch.utils.tensorboard.SummaryWriter``."""

    def __init__(self, writer: Any, window: int = 100) -> None:
        self.writer = writer
        self._outcomes: deque[str] = deque(maxlen=window)

    def episode(self, row: Mapping[str, Any]) -> None:
        """One row of metrics.csv (sim_harness.rl.runlog.METRIC_FIELDS)."""
        step = int(row["episode"]) + 1
        add = self.writer.add_scalar
        add("episode/reward", float(row["reward"]), step)
        add("episode/length", int(row["length"]), step)
        add("episode/progress_m", float(row["progress_m"]), step)
        add("schedule/epsilon", float(row["epsilon"]), step)
        add("schedule/gamma", float(row["gamma"]), step)
        loss = float(row["loss"])
        if math.isfinite(loss):
            add("train/loss", loss, step)
        self._outcomes.append(str(row["outcome"]))
        n = len(self._outcomes)
        for outcome in OUTCOMES:
            add(f"outcome/{outcome}", sum(o == outcome for o in self._outcomes) / n, step)

    def evaluation(self, episode: int, scores: Mapping[str, float]) -> None:
        for key, value in scores.items():
            self.writer.add_scalar(f"eval/{key}", float(value), episode)
        self.writer.flush()

    def close(self) -> None:
        self.writer.close()


_warned = False


def open_tensorboard(run_dir: Path) -> TensorBoardLog | None:
    """A log writing to ``run_dir/tb``; None (with one warning per process) without tensorboard."""
    global _warned
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        if not _warned:
            hint = 'pip install "quadnav[tensorboard]"'
            log.warning("tensorboard_missing", hint=hint, run_dir=str(run_dir))
            _warned = True
        return None
    return TensorBoardLog(SummaryWriter(log_dir=str(run_dir / "tb")))
