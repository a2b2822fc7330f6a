"""The run directory: config, per-episode metrics (CSV + JSON), the reward-curve PNG.

Files only; no learning here. A run directory is ``<out_dir>/<name>__seed<k>__<YYYYmmdd-HHMMSS>/``
holding ``config.json``, ``metrics.csv``, ``metrics.json``, ``reward_curve.png``, ``evals.csv`` and
``evals.json`` (with ``eval_every``), ``tb/`` (TensorBoard event files),
``checkpoints/`` (``latest.pt``, ``final.pt`` loadable by ``load_checkpoint``) and ``state.pt`` +
``state.json`` (what ``--resume`` needs).
"""

from __future__ import annotations

import csv
import json
import platform
import subprocess
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

__all__ = [
    "METRIC_FIELDS",
    "git_commit",
    "make_run_dir",
    "platform_info",
    "plot_reward_curve",
    "read_evals",
    "read_metrics",
    "write_evals",
    "write_metrics",
]

METRIC_FIELDS = (
    "episode",
    "world",
    "reward",
    "length",
    "outcome",
    "progress_m",
    "epsilon",
    "gamma",
    "loss",
    "env_steps",
    "wall_s",
)
"""Columns of metrics.csv (one row per finished episode, in finishing order)."""


def make_run_dir(out_dir: str | Path, name: str, seed: int) -> Path:
    """Create and return a fresh run directory named from the experiment, seed and time."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = Path(out_dir) / f"{name}__seed{seed}__{stamp}"
    suffix = 1
    while path.exists():
        path = Path(out_dir) / f"{name}__seed{seed}__{stamp}-{suffix}"
        suffix += 1
    (path / "checkpoints").mkdir(parents=True)
    return path


def git_commit() -> str:
    """The commit of the source tree (with ``-dirty`` if it has local changes), or ``unknown``."""
    here = Path(__file__).resolve().parent
    try:
        rev = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=5, check=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
            timeout=5,
            check=True,
        ).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    return rev + ("-dirty" if dirty else "")


def _cpu_model() -> str:
    """The CPU's model name as the kernel reports it (Linux), else what ``platform`` knows."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            for line in fh:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def platform_info() -> dict[str, str]:
    """What training's numerics depend on beyond the code and the seed: the CPU, the kernels
    torch dispatches to, and the versions of the numeric libraries. A recipe gives the same
    weights bit for bit only where these agree (docs/results.md, "The recipes")."""
    import numba
    import torch

    return {
        "machine": platform.machine(),
        "cpu": _cpu_model(),
        "torch_cpu_capability": str(torch.backends.cpu.get_cpu_capability()),
        "python": platform.python_version(),
        "torch": str(torch.__version__),
        "numpy": str(np.__version__),
        "numba": str(numba.__version__),
    }


def write_metrics(run_dir: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Write metrics.csv and metrics.json (atomically: write then rename)."""
    tmp = run_dir / "metrics.csv.tmp"
    with tmp.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=METRIC_FIELDS)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(run_dir / "metrics.csv")
    tmp = run_dir / "metrics.json.tmp"
    tmp.write_text(json.dumps(list(rows)), encoding="utf-8")
    tmp.replace(run_dir / "metrics.json")


def write_evals(run_dir: Path, rows: Sequence[dict[str, Any]]) -> None:
    """Write evals.csv and evals.json (one row per evaluation during training), atomically."""
    fields = list(rows[0]) if rows else ["episode"]
    tmp = run_dir / "evals.csv.tmp"
    with tmp.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=fields)
        writer.writeheader()
        writer.writerows(rows)
    tmp.replace(run_dir / "evals.csv")
    tmp = run_dir / "evals.json.tmp"
    tmp.write_text(json.dumps(list(rows)), encoding="utf-8")
    tmp.replace(run_dir / "evals.json")


def read_evals(run_dir: Path) -> list[dict[str, Any]]:
    """The rows of evals.json (empty if there is none)."""
    path = run_dir / "evals.json"
    if not path.is_file():
        return []
    return list(json.loads(path.read_text(encoding="utf-8")))


def read_metrics(run_dir: Path) -> list[dict[str, Any]]:
    """The rows of metrics.json (empty if there is none yet)."""
    path = run_dir / "metrics.json"
    if not path.is_file():
        return []
    return list(json.loads(path.read_text(encoding="utf-8")))


def plot_reward_curve(rows: Sequence[dict[str, Any]], path: Path, title: str, window: int = 50) -> Path:
    """Per-episode reward and its running mean over ``window`` episodes (like the paper's Fig. 4)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rewards = np.array([float(r["reward"]) for r in rows])
    episodes = np.arange(1, len(rewards) + 1)
    fig, ax = plt.subplots(figsize=(6.0, 3.2), dpi=100)
    ax.plot(episodes, rewards, lw=0.5, alpha=0.35, color="tab:blue", label="episode reward")
    if len(rewards) >= 1:
        w = max(1, min(window, len(rewards)))
        avg = np.convolve(rewards, np.ones(w) / w, mode="valid")
        ax.plot(episodes[w - 1 :], avg, lw=1.8, color="tab:red", label=f"average over {w} episodes")
    ax.set_xlabel("episode")
    ax.set_ylabel("total reward")
    ax.set_title(title, fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    fig.savefig(path)
    plt.close(fig)
    return path
