"""Run several training configurations in a process pool, then evaluate each final model.

The dependency-free sweep (and the baseline of ``benchmarks/bench_sweep.py``); ``quadnav-sim sweep``
runs sweeps on Ray Tune instead (sim_harness.rl.tune_sweep: search spaces, early stopping, failed
trials recorded, resume, clusters).

``python -m sim_harness.rl.sweep --out DIR --jobs 14 --trials 10 --spec NAME:key=value,key=value ...``
Each spec is a :class:`TrainConfig` override (``name`` = NAME; tuples as ``1+2+3``; several seeds as
``seed=0+1+2`` expand to one job per seed). Every job is one ``train`` in its own process (one
torch and one numba thread), then a greedy evaluation on the ten paper worlds; ``DIR/sweep.json``
holds every job's config, throughput and evaluation summary (train worlds / held-out / all).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import sys
import time
import typing
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sim_harness.rl.config import TrainConfig
    from sim_harness.rl.train import TrainResult

__all__ = ["evaluate_run", "main", "parse_spec", "run_job"]


def parse_spec(spec: str) -> list[dict[str, Any]]:
    """``NAME:key=v,key=v`` -> one override dict per seed (``seed=0+1`` gives two)."""
    from sim_harness.rl.config import TrainConfig

    name, _, rest = spec.partition(":")
    hints = typing.get_type_hints(TrainConfig)
    base: dict[str, Any] = {"name": name}
    seeds = [0]
    for item in filter(None, rest.split(",")):
        key, _, value = item.partition("=")
        key = key.strip().replace("-", "_")
        if key not in hints:
            raise SystemExit(f"sweep: spec {spec!r}: unknown TrainConfig field {key!r}")
        tp = hints[key]
        if key == "seed":
            seeds = [int(v) for v in value.split("+")]
        elif tp is bool:
            base[key] = value.lower() in ("1", "true", "yes")
        elif typing.get_origin(tp) is tuple:
            item_tp = typing.get_args(tp)[0]
            base[key] = tuple(item_tp(v) for v in value.split("+"))
        else:
            base[key] = tp(value)
    return [{**base, "seed": s} for s in seeds]


def run_job(args: tuple[dict[str, Any], str, int]) -> dict[str, Any]:
    """Train one configuration, evaluate its final model; returns a JSON-ready record."""
    overrides, out_dir, trials = args
    from sim_harness.rl.config import load_train_config
    from sim_harness.rl.threads import limit_threads
    from sim_harness.rl.train import train

    limit_threads(1, 1)
    cfg = load_train_config({**overrides, "out_dir": out_dir}, source="sweep spec")
    t0 = time.monotonic()
    result = train(cfg, progress=False)
    return evaluate_run(cfg, result, trials, t0)


def evaluate_run(cfg: TrainConfig, result: TrainResult, trials: int, started: float) -> dict[str, Any]:
    """The record of a finished run: its config and throughput, and a greedy evaluation of its
    final model on the ten paper worlds (``trials`` per world, seed 1000) by part (train worlds,
    held-out, all). ``started``: ``time.monotonic()`` when the job began."""
    from quadnav_onboard.policy import Policy
    from sim_harness.rl.evaluate import env_config_for_policy, evaluate, policy_greedy_fn, scores, summarize
    from sim_harness.world import TEST_WORLD_IDS, TRAIN_WORLD_IDS, load_world, paper_world_path

    policy = Policy.from_path(result.model_path)
    worlds = [load_world(paper_world_path(i)) for i in range(1, 11)]
    rows = evaluate(
        policy_greedy_fn(policy), worlds, trials, seed=1000, env_config=env_config_for_policy(policy)
    )
    names_train = {load_world(paper_world_path(i)).name for i in TRAIN_WORLD_IDS}
    names_test = {load_world(paper_world_path(i)).name for i in TEST_WORLD_IDS}
    return {
        "config": cfg.to_dict(),
        "run_dir": str(result.run_dir),
        "episodes": result.episodes,
        "env_steps": result.env_steps,
        "updates": result.updates,
        "train_wall_s": round(result.wall_s, 1),
        "env_steps_per_s": round(result.env_steps_per_s, 1),
        "updates_per_s": round(result.updates_per_s, 1),
        "total_wall_s": round(time.monotonic() - started, 1),
        "eval_trials": trials,
        "eval_all": summarize(rows),
        "eval_train_worlds": summarize([r for r in rows if r.world in names_train]),
        "scores_train_worlds": scores([r for r in rows if r.world in names_train]),
        "eval_held_out": summarize([r for r in rows if r.world in names_test]),
        "eval_rows": [r.to_dict() for r in rows],
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m sim_harness.rl.sweep", description=__doc__)
    p.add_argument("--out", required=True, help="output folder (run dirs and sweep.json)")
    p.add_argument("--jobs", type=int, default=2, help="parallel processes")
    p.add_argument("--trials", type=int, default=10, help="evaluation trials per world")
    p.add_argument("--spec", nargs="+", required=True, help="NAME:key=value,... (see module doc)")
    a = p.parse_args(argv)
    jobs = [job for spec in a.spec for job in parse_spec(spec)]
    Path(a.out).mkdir(parents=True, exist_ok=True)
    print(f"sweep: {len(jobs)} jobs on {a.jobs} processes", flush=True)
    records = []
    ctx = mp.get_context("spawn")
    with ctx.Pool(a.jobs, maxtasksperchild=1) as pool:
        for rec in pool.imap_unordered(run_job, [(j, a.out, a.trials) for j in jobs]):
            records.append(rec)
            s, h, a_ = rec["eval_train_worlds"], rec["eval_held_out"], rec["eval_all"]
            name, seed = rec["config"]["name"], rec["config"]["seed"]
            print(
                f"{name:<24} seed {seed}: goal {a_['success_rate']:.0%} safe {a_['collision_free_rate']:.0%} "
                f"(train {s['success_rate']:.0%}, held-out {h['success_rate']:.0%}) {rec['episodes']} ep, "
                f"{rec['env_steps']} steps, {rec['updates']} upd, {rec['train_wall_s']} s",
                flush=True,
            )
            (Path(a.out) / "sweep.json").write_text(json.dumps(records, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
