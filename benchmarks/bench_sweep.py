"""A local Ray sweep against the process pool: the same trials, wall time side by side.

    .venv/bin/python benchmarks/bench_sweep.py [--episodes 2000] [--seeds 4] [--json OUT]

The trials: the paper's recipe (TrainConfig defaults) with seeds 0..N-1, each trained and then
evaluated on the ten paper worlds (10 trials per world, seed 1000), two at a time on a 2-core
machine. Runs, each a fresh process timed from start to exit:

- ``pool``: ``python -m sim_harness.rl.sweep --jobs 2`` (the dependency-free process pool);
- ``ray``: ``quadnav-sim sweep`` with its defaults (scores reported every 500 episodes, one
  episode per training world: what ASHA reads; ``--eval-trials N`` passes N);
- ``ray_no_midrun_eval``: ``quadnav-sim sweep --eval-every 0`` (the pool's work exactly).

The target: ``ray`` within 15 % of ``pool``. Record the machine load beside the figures: on a
shared machine they are pessimistic and noisy.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TARGET_RATIO = 1.15


def _timed(cmd: list[str]) -> float:
    t0 = time.monotonic()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.monotonic() - t0


def _train_wall_s(sweep_json: Path) -> float:
    return round(sum(float(r.get("train_wall_s", 0.0)) for r in json.loads(sweep_json.read_text())), 1)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--episodes", type=int, default=2000, help="training episodes per trial (the paper: 2000)")
    p.add_argument("--seeds", type=int, default=4, help="trials (seeds 0..N-1)")
    p.add_argument("--jobs", type=int, default=2, help="trials at once (the pool's processes, Ray's CPUs)")
    p.add_argument("--skip-no-eval", action="store_true", help="leave out the ray_no_midrun_eval run")
    p.add_argument("--eval-trials", type=int, default=None, help="the ray run's --eval-trials")
    p.add_argument("--json", default=None, help="write the figures here")
    args = p.parse_args(argv)
    seeds = [str(s) for s in range(args.seeds)]
    py = sys.executable
    runs: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        cases = {
            "pool": [py, "-m", "sim_harness.rl.sweep", "--out", f"{tmp}/pool", "--jobs", str(args.jobs),
                     "--trials", "10", "--spec", f"bench:episodes={args.episodes},seed={'+'.join(seeds)}"],
            "ray": [py, "-m", "sim_harness.cli", "sweep", "--out", f"{tmp}/ray", "--name", "bench",
                    "--set", f"episodes={args.episodes}", "--seeds", *seeds, "--final-trials", "10",
                    "--num-cpus", str(args.jobs), "--no-progress",
                    *(["--eval-trials", str(args.eval_trials)] if args.eval_trials else [])],
        }  # fmt: skip
        if not args.skip_no_eval:
            cases["ray_no_midrun_eval"] = [*cases["ray"], "--eval-every", "0"]
            cases["ray_no_midrun_eval"][cases["ray"].index(f"{tmp}/ray")] = f"{tmp}/ray0"
        for name, cmd in cases.items():
            load = os.getloadavg()[0]
            wall = _timed(cmd)
            out = Path(cmd[cmd.index("--out") + 1])
            runs[name] = {
                "wall_s": round(wall, 1),
                "sum_train_wall_s": _train_wall_s(out / "sweep.json"),
                "load_before": round(load, 2),
                "load_after": round(os.getloadavg()[0], 2),
            }
            print(f"{name:<20} {wall:7.1f} s wall (trials' training {runs[name]['sum_train_wall_s']} s; "
                  f"load {load:.2f} -> {runs[name]['load_after']:.2f})", flush=True)  # fmt: skip
    ratio = runs["ray"]["wall_s"] / runs["pool"]["wall_s"]
    summary = {
        "episodes": args.episodes,
        "trials": args.seeds,
        "jobs": args.jobs,
        "runs": runs,
        "ray_over_pool": round(ratio, 3),
        "target_ratio": TARGET_RATIO,
        "met": ratio <= TARGET_RATIO,
        "cpus": os.cpu_count(),
    }
    print(f"ray / pool = {ratio:.3f} (target <= {TARGET_RATIO}: {'met' if summary['met'] else 'not met'})")
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
