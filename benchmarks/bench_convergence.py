"""The paper's convergence study (Camci & Kayacan, Fig. 4): the paper recipe trained for 100, 200,
500, 1000 and 2000 episodes, the ε/γ schedules stretched to each budget, three seeds each.

    .venv/bin/python benchmarks/bench_convergence.py [--budgets 100 200 500 1000 2000]
        [--seeds 0 1 2] [--png docs/figures/convergence.png] [--json docs/figures/convergence.json]

Each run is ``quadnav-sim train`` in-process with the defaults of TrainConfig (the paper's recipe)
and ``--episodes B``: the ε decay 1.0 -> 0.1 and the γ gain 0.01 -> 0.99 ramp over the first 80 %
of the B episodes (``schedule_fraction``), as in each of the paper's five training runs. The figure
has one panel per budget (the running mean of the episode reward over ``window`` episodes: the
mean over the seeds, and the band from the lowest to the highest seed), and a sixth panel with
each budget's final average reward (the mean reward of the last 20 % of its episodes, the flat
part of the schedules). The JSON holds every curve and figure, the machine's load and the wall
time of each run. Runs go one after another (``--jobs N``: N at a time, the longest first;
``--cache DIR`` keeps each finished run, so a killed study resumes).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

BUDGETS = (100, 200, 500, 1000, 2000)
"""The paper's five training budgets (episodes)."""
SEEDS = (0, 1, 2)
WINDOW = 50
"""Running-mean window (episodes), capped at a fifth of the budget."""
FINAL_FRACTION = 0.2
"""Share of the last episodes whose mean reward is a budget's final average reward."""


def window_for(budget: int) -> int:
    return max(1, min(WINDOW, budget // 5))


def running_mean(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of the last ``window`` values at each episode (fewer at the start)."""
    csum = np.cumsum(np.concatenate([[0.0], values]))
    idx = np.arange(1, len(values) + 1)
    lo = np.maximum(0, idx - window)
    return (csum[idx] - csum[lo]) / (idx - lo)


def train_one(budget: int, seed: int, cache: str | None = None) -> dict[str, Any]:
    """One paper-recipe run of ``budget`` episodes: its per-episode rewards and wall time (read
    from ``cache/B_S.json`` when an earlier invocation left it there, and written there after)."""
    cached = Path(cache) / f"{budget}_{seed}.json" if cache else None
    if cached is not None and cached.is_file():
        return json.loads(cached.read_text(encoding="utf-8"))
    run = _train(budget, seed)
    if cached is not None:
        cached.parent.mkdir(parents=True, exist_ok=True)
        cached.write_text(json.dumps(run), encoding="utf-8")
    return run


def _train(budget: int, seed: int) -> dict[str, Any]:
    from sim_harness.rl.config import TrainConfig
    from sim_harness.rl.train import train

    with tempfile.TemporaryDirectory() as tmp:
        cfg = TrainConfig(name=f"conv{budget}", seed=seed, episodes=budget, out_dir=tmp, tensorboard=False)
        t0 = time.monotonic()
        result = train(cfg, progress=False, evaluate_at_end=False)
        wall = time.monotonic() - t0
        rows = json.loads((result.run_dir / "metrics.json").read_text(encoding="utf-8"))
    rewards = [float(r["reward"]) for r in rows]
    goals = [r["outcome"] == "goal" for r in rows]
    return {"budget": budget, "seed": seed, "wall_s": round(wall, 1), "rewards": rewards, "goals": goals}


def summarise(budget: int, runs: list[dict[str, Any]]) -> dict[str, Any]:
    w = window_for(budget)
    curves = np.array([running_mean(np.asarray(r["rewards"]), w) for r in runs])
    tail = max(1, round(FINAL_FRACTION * budget))
    finals = [float(np.mean(r["rewards"][-tail:])) for r in runs]
    goal_tail = [float(np.mean(r["goals"][-tail:])) for r in runs]
    return {
        "budget": budget,
        "seeds": [r["seed"] for r in runs],
        "window": w,
        "wall_s": [r["wall_s"] for r in runs],
        "curve_mean": np.round(curves.mean(axis=0), 4).tolist(),
        "curve_min": np.round(curves.min(axis=0), 4).tolist(),
        "curve_max": np.round(curves.max(axis=0), 4).tolist(),
        "final_avg_reward_per_seed": [round(f, 3) for f in finals],
        "final_avg_reward_mean": round(float(np.mean(finals)), 3),
        "final_goal_rate_per_seed": [round(g, 3) for g in goal_tail],
        "rewards_per_seed": [r["rewards"] for r in runs],
    }


def plot(summaries: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 3, figsize=(13, 7), constrained_layout=True)
    flat = axes.ravel()
    for ax, s in zip(flat, summaries, strict=False):
        x = np.arange(1, s["budget"] + 1)
        ax.fill_between(
            x,
            s["curve_min"],
            s["curve_max"],
            color="tab:blue",
            alpha=0.25,
            lw=0,
            label=f"lowest-highest of {len(s['seeds'])} seeds",
        )
        ax.plot(x, s["curve_mean"], color="tab:blue", lw=1.6, label="mean over seeds")
        ax.axvline(0.8 * s["budget"], color="grey", ls=":", lw=1, label="end of the ε/γ ramp")
        ax.set_title(f"{s['budget']} episodes (running mean over {s['window']})")
        ax.set_xlabel("episode")
        ax.set_ylabel("average reward")
        ax.grid(alpha=0.3)
    lo = min(min(s["curve_min"]) for s in summaries)
    hi = max(max(s["curve_max"]) for s in summaries)
    for ax in flat[: len(summaries)]:  # one reward scale, so the panels compare
        ax.set_ylim(lo - 0.05 * (hi - lo), hi + 0.05 * (hi - lo))
    flat[0].legend(fontsize=8, loc="upper left")
    ax = flat[len(summaries)] if len(summaries) < len(flat) else None
    if ax is not None:
        budgets = [s["budget"] for s in summaries]
        for s in summaries:
            ax.scatter(
                [s["budget"]] * len(s["final_avg_reward_per_seed"]),
                s["final_avg_reward_per_seed"],
                color="tab:blue",
                s=14,
                alpha=0.6,
            )
        ax.plot(budgets, [s["final_avg_reward_mean"] for s in summaries], "o-", color="tab:red", label="mean")
        ax.set_xscale("log")
        ax.set_xticks(budgets, [str(b) for b in budgets])
        ax.set_title(f"final average reward (last {int(FINAL_FRACTION * 100)} % of episodes)")
        ax.set_xlabel("training budget (episodes)")
        ax.set_ylabel("average reward")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for extra in flat[len(summaries) + 1 :]:
        extra.set_visible(False)
    fig.suptitle("The paper recipe's average reward per training budget (cf. Camci & Kayacan, Fig. 4)")
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--budgets", type=int, nargs="+", default=list(BUDGETS), help="episodes per training run")
    p.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS), help="training seeds per budget")
    p.add_argument("--jobs", type=int, default=1, help="runs at a time (1-16; default 1)")
    p.add_argument("--png", default="docs/figures/convergence.png", help="the figure")
    p.add_argument("--json", default="docs/figures/convergence.json", help="the curves and figures")
    p.add_argument(
        "--cache", default=None, help="folder of finished runs (B_S.json): reused, so a killed study resumes"
    )
    p.add_argument(
        "--cached-only",
        action="store_true",
        help="train nothing: draw the runs already in --cache (a study cut short; the JSON lists the seeds)",
    )
    args = p.parse_args(argv)
    if args.cached_only and not args.cache:
        p.error("--cached-only needs --cache DIR")
    if not 1 <= args.jobs <= 16:
        p.error(f"--jobs: bad value {args.jobs}: range [1, 16]")
    if any(not 1 <= b <= 100_000 for b in args.budgets):
        p.error(f"--budgets: bad value {args.budgets}: each in [1, 100000]")
    if any(not 0 <= s < 2**32 for s in args.seeds):
        p.error(f"--seeds: bad value {args.seeds}: each in [0, 2**32)")
    if len(args.budgets) > 5:
        p.error("--budgets: at most 5 (one panel each)")
    jobs = [(b, s) for b in sorted(args.budgets, reverse=True) for s in args.seeds]  # the longest first
    if args.cached_only:
        jobs = [(b, s) for b, s in jobs if (Path(args.cache) / f"{b}_{s}.json").is_file()]
    load_before = os.getloadavg()[0]
    t0 = time.monotonic()
    done: dict[tuple[int, int], dict[str, Any]] = {}
    with ProcessPoolExecutor(max_workers=args.jobs) as pool:
        futures = {pool.submit(train_one, b, s, args.cache): (b, s) for b, s in jobs}
        for fut in as_completed(futures):
            b, s = futures[fut]
            run = fut.result()
            done[(b, s)] = run
            tail = max(1, round(FINAL_FRACTION * b))
            print(
                f"[{len(done)}/{len(jobs)}] budget {b} seed {s}: {run['wall_s']:.1f} s, final average "
                f"reward {np.mean(run['rewards'][-tail:]):.3f} (elapsed {time.monotonic() - t0:.0f} s)",
                flush=True,
            )
    summaries = [
        summarise(b, [done[(b, s)] for s in args.seeds if (b, s) in done])
        for b in sorted(args.budgets)
        if any((b, s) in done for s in args.seeds)
    ]
    if not summaries:
        print("no finished runs to draw", file=sys.stderr)
        return 1
    plot(summaries, Path(args.png))
    from sim_harness.rl.config import TrainConfig
    from sim_harness.rl.runlog import git_commit

    out = {
        "benchmark": "convergence",
        "command": "python benchmarks/bench_convergence.py "
        + " ".join(argv if argv is not None else sys.argv[1:]),
        "recipe": {
            k: v for k, v in dataclasses.asdict(TrainConfig()).items() if k not in ("name", "out_dir")
        },
        "git_commit": git_commit(),
        "cpu_count": os.cpu_count(),
        "load_avg_1min_before": round(load_before, 2),
        "load_avg_1min_after": round(os.getloadavg()[0], 2),
        "wall_s": round(time.monotonic() - t0, 1),
        "runs_wall_s_sum": round(sum(r["wall_s"] for r in done.values()), 1),
        "final_fraction": FINAL_FRACTION,
        "budgets": summaries,
    }
    Path(args.json).parent.mkdir(parents=True, exist_ok=True)
    Path(args.json).write_text(json.dumps(out) + "\n", encoding="utf-8")
    for s in summaries:
        print(
            f"budget {s['budget']:5d}: final average reward {s['final_avg_reward_mean']:.3f} "
            f"(seeds {s['final_avg_reward_per_seed']}), goal rate {s['final_goal_rate_per_seed']}"
        )
    print(f"figure: {args.png}\njson:   {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
