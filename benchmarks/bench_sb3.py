"""Stable-Baselines3's DQN on the navigation env: env steps/s, training included, and the threads.

    .venv/bin/python benchmarks/bench_sb3.py [--steps 20000] [--json OUT]

Each case runs in its own process (thread counts are per process) and times ``model.learn`` after
a warm-up (numba kernels compiled, the replay past ``learning_starts``):

- ``single_*``: SB3's DQN on ``gymnasium.make("quadnav/QuadNav-v0")`` (one env, SB3's
  ``MultiInputPolicy`` with the paper's lanes, SB3's defaults: an update every 4 steps), with
  torch's and numba's default thread counts (``numba`` left to all cores: ``sim_threads=None``),
  with only numba held to one, only torch, and both (sim_harness.rl.threads).
- ``batched``: :func:`sim_harness.sb3.train_dqn` (16 envs stepped in one batch by
  :class:`sim_harness.sb3.QuadNavSB3VecEnv`, one update of batch 64 per vectorised step, one
  thread each). The target: >= 1,000 env steps/s on 2 cores, training included.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

TARGET_STEPS_PER_S = 1000.0

CASES = {
    "single_default_threads": ("single", None, None),
    "single_numba_1": ("single", None, 1),
    "single_torch_1": ("single", 1, None),
    "single_both_1": ("single", 1, 1),
    "batched_both_1": ("batched", 1, 1),
}
"""name -> (env, torch threads, numba threads); None = the library's default."""


def _case(kind: str, torch_threads: int | None, numba_threads: int | None, steps: int) -> dict:
    import gymnasium as gym
    import numba
    import torch

    import sim_harness.env  # noqa: F401  (registers quadnav/QuadNav-v0)
    from sim_harness.sb3 import paper_policy_kwargs, train_dqn

    if torch_threads:
        torch.set_num_threads(torch_threads)
    if kind == "single":
        from stable_baselines3 import DQN

        env = gym.make("quadnav/QuadNav-v0", sim_threads=numba_threads)
        model = DQN(
            "MultiInputPolicy",
            env,
            policy_kwargs=paper_policy_kwargs(),
            learning_starts=500,
            buffer_size=20_000,
            seed=0,
            device="cpu",
        )
        model.learn(1000)  # warm-up: kernels compiled, updates running
        t0 = time.monotonic()
        model.learn(steps, reset_num_timesteps=False)
        wall = time.monotonic() - t0
        updates = steps // 4
    else:
        t0 = time.monotonic()
        train_dqn(timesteps=2000, n_envs=16, learning_starts=500)  # warm-up
        t0 = time.monotonic()
        train_dqn(timesteps=steps, n_envs=16, learning_starts=1000)
        wall = time.monotonic() - t0
        updates = (steps - 1000) // 16
    return {
        "env": kind,
        "torch_threads": torch.get_num_threads(),
        "numba_threads": numba.get_num_threads(),
        "env_steps": steps,
        "updates_about": updates,
        "wall_s": round(wall, 2),
        "env_steps_per_s": round(steps / wall, 1),
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--steps", type=int, default=20_000, help="timed env steps per case")
    p.add_argument("--single-steps", type=int, default=3_000, help="timed env steps of the one-env cases")
    p.add_argument("--json", default=None, help="write the figures here")
    p.add_argument("--case", default=None, help=argparse.SUPPRESS)  # one case, in a child process
    args = p.parse_args(argv)
    if args.case:
        kind, tt, nt = CASES[args.case]
        steps = args.single_steps if kind == "single" else args.steps
        print(json.dumps(_case(kind, tt, nt, steps)))
        return 0
    results = {}
    load_before = os.getloadavg()[0]
    for name in CASES:
        cmd = [
            sys.executable,
            __file__,
            "--case",
            name,
            "--steps",
            str(args.steps),
            "--single-steps",
            str(args.single_steps),
        ]
        out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout.strip().splitlines()[-1]
        results[name] = json.loads(out)
        r = results[name]
        print(
            f"{name:<24} torch {r['torch_threads']} numba {r['numba_threads']}: "
            f"{r['env_steps_per_s']:>7.0f} env steps/s ({r['env_steps']} steps, {r['wall_s']} s)",
            flush=True,
        )
    best = results["batched_both_1"]["env_steps_per_s"]
    summary = {
        "cases": results,
        "target_env_steps_per_s": TARGET_STEPS_PER_S,
        "met": best >= TARGET_STEPS_PER_S,
        "cpus": os.cpu_count(),
        "load_before": round(load_before, 2),
        "load_after": round(os.getloadavg()[0], 2),
    }
    print(
        f"batched SB3 DQN: {best:.0f} env steps/s (target {TARGET_STEPS_PER_S:.0f}: "
        f"{'met' if summary['met'] else 'not met'}); load {summary['load_before']} -> {summary['load_after']}"
    )
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(summary, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
