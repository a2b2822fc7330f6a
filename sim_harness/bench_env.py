"""Environment-steps-per-second benchmark (render + dynamics + collision + reward), vectorised.

``run()`` steps :class:`sim_harness.env.VecQuadNavEnv` over the seven training worlds with random
actions (auto-reset on) and returns the figures as a dict; ``quadnav-sim bench`` prints them.
The target: >= 5,000 env steps/s on a 2-core CPU.
"""

from __future__ import annotations

import os
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["TARGET_STEPS_PER_S", "run"]

TARGET_STEPS_PER_S = 5_000.0
"""The target for vectorised env steps per second."""


def _one(n_envs: int, seconds: float, seed: int) -> dict[str, Any]:
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.world import TRAIN_WORLD_IDS, load_world, paper_world_path

    worlds = [load_world(paper_world_path(i)) for i in TRAIN_WORLD_IDS]
    env = VecQuadNavEnv(worlds, n_envs, seed=seed)
    rng = np.random.default_rng(seed)
    env.reset()
    env.step(rng.integers(0, 18, n_envs))  # warm up (numba compilation, caches)
    steps, episodes = 0, 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, _, term, trunc, _ = env.step(rng.integers(0, 18, n_envs))
        steps += n_envs
        episodes += int((term | trunc).sum())
    wall = time.perf_counter() - t0
    return {
        "n_envs": n_envs,
        "env_steps": steps,
        "episodes": episodes,
        "wall_s": round(wall, 3),
        "env_steps_per_s": round(steps / wall, 1),
    }


def run(
    n_envs: Sequence[int] = (16, 64, 256), seconds: float = 3.0, seed: int = 0, sim_threads: int | None = None
) -> dict[str, Any]:
    """Measure env steps/s for each vectorisation width; returns a JSON-ready dict.

    ``sim_threads``: numba threads for the render/collision kernels (None = leave as is).
    """
    import numba

    if sim_threads:
        numba.set_num_threads(min(sim_threads, numba.config.NUMBA_NUM_THREADS))
    results = [_one(n, seconds, seed) for n in n_envs]
    best = max(r["env_steps_per_s"] for r in results)
    return {
        "benchmark": "env_steps",
        "what": "VecQuadNavEnv.step over the 7 training worlds, random actions, auto-reset: "
        "32x32 depth render + 20-substep quad tracking + swept collision + reward",
        "uses": "numpy vectorisation over envs; the sim_harness.render and collision kernels",
        "cpu_count": os.cpu_count(),
        "numba_threads": numba.get_num_threads(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "results": results,
        "best_env_steps_per_s": best,
        "target_env_steps_per_s": TARGET_STEPS_PER_S,
        "meets_target": best >= TARGET_STEPS_PER_S,
    }


if __name__ == "__main__":
    import json

    print(json.dumps(run(), indent=2))
