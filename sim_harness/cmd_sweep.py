"""``quadnav-sim sweep``: many training runs on Ray Tune (the ``sweep`` extra), locally or on a cluster.

Every trial is one ``quadnav-sim train`` with TrainConfig overrides from a sweep file (YAML, see
sim_harness.rl.sweep_space) and/or ``--set``/``--grid``/``--sample``/``--seeds``; docs/training.md
shows a sweep on one machine and on a Ray cluster.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["add_parser", "run"]

EXIT_USAGE = 2
EXIT_NO_EXTRA = 3
"""Exit status when Ray Tune is not installed (the ``sweep`` extra)."""


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "sweep",
        help="train many configurations on Ray Tune (search spaces, seeds, ASHA, resume, clusters)",
        description="Run a sweep of training runs on Ray Tune (pip install 'quadnav[sweep]'). Writes "
        "OUT/sweep.json, OUT/sweep.csv and OUT/best.json; --resume continues a killed sweep. Exit "
        "status 0 when at least one trial finished, 1 when every trial failed, 2 on bad input, 3 "
        "without Ray.",
    )
    p.add_argument("--out", required=True, help="the sweep's folder (runs, tables, Ray's state)")
    p.add_argument(
        "--config", type=Path, default=None, help="sweep file (YAML: name, base, grid, sample, seeds)"
    )
    p.add_argument("--name", default=None, help="experiment name (default: the file's, else 'sweep')")
    p.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", help="override of every trial")
    p.add_argument("--grid", action="append", default=[], metavar="KEY=V1,V2", help="a grid dimension")
    p.add_argument(
        "--sample",
        action="append",
        default=[],
        metavar="KEY=KIND:A:B",
        help="a sampled dimension; KIND: choice, uniform, loguniform, randint (inclusive)",
    )
    p.add_argument("--seeds", type=int, nargs="+", default=None, help="seeds (a grid dimension)")
    p.add_argument("--num-samples", type=int, default=None, help="repeats of the grid (fresh draws)")
    p.add_argument("--resume", action="store_true", help="continue the killed sweep in --out")
    p.add_argument("--address", default=None, help="Ray cluster to join, e.g. 10.0.0.5:6379 (default: local)")
    p.add_argument("--num-cpus", type=int, default=None, help="CPUs of the local Ray (default: all cores)")
    p.add_argument("--max-concurrent", type=int, default=0, help="most trials at once (0: one per CPU)")
    p.add_argument(
        "--scheduler", choices=("fifo", "asha"), default="fifo", help="asha stops bad trials early"
    )
    p.add_argument(
        "--metric",
        choices=("goal_rate", "collision_free_rate", "distance_m", "reward"),
        default="goal_rate",
        help="score on the training worlds that ASHA maximises",
    )
    p.add_argument("--grace-period", type=int, default=500, help="episodes before ASHA may stop a trial")
    p.add_argument("--eval-every", type=int, default=500, help="episodes between scores reported in training")
    p.add_argument(
        "--eval-trials", type=int, default=1, help="episodes per training world per evaluation (default 1)"
    )
    p.add_argument("--final-trials", type=int, default=10, help="final evaluation trials per paper world")
    p.add_argument("--dry-run", action="store_true", help="print the trials of the grid and exit")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _usage(msg: str) -> int:
    print(f"quadnav-sim sweep: {msg}", file=sys.stderr)
    return EXIT_USAGE


def run(args: argparse.Namespace) -> int:
    from quadnav_onboard.config import ConfigError
    from sim_harness.rl.sweep_space import load_sweep_file, merge_command_line, spec_from_mapping
    from sim_harness.rl.tune_sweep import SweepOptions, SweepUnavailable, resume_sweep, run_sweep

    out = Path(args.out).resolve()
    for flag in ("max_concurrent", "eval_every"):
        if getattr(args, flag) < 0:
            return _usage(f"--{flag.replace('_', '-')} must be >= 0")
    for flag in ("eval_trials", "final_trials", "grace_period"):
        if getattr(args, flag) < 1:
            return _usage(f"--{flag.replace('_', '-')} must be >= 1")
    try:
        if args.resume:
            outcome = resume_sweep(out, progress=not args.no_progress, address=args.address)
        else:
            data = load_sweep_file(args.config) if args.config is not None else {}
            merged = merge_command_line(
                data,
                name=args.name,
                sets=args.set,
                grids=args.grid,
                samples=args.sample,
                seeds=args.seeds,
                num_samples=args.num_samples,
            )
            spec = spec_from_mapping(merged, str(args.config or "command line"))
            if args.dry_run:
                for point in spec.grid_points():
                    print(point)
                print(f"{spec.n_trials()} trials ({len(spec.sample)} sampled fields)")
                return 0
            options = SweepOptions(
                out_dir=str(out),
                eval_every=args.eval_every,
                eval_trials=args.eval_trials,
                final_trials=args.final_trials,
                scheduler=args.scheduler,
                metric=args.metric,
                grace_period=args.grace_period,
                max_concurrent=args.max_concurrent,
                address=args.address,
                num_cpus=args.num_cpus,
            )
            outcome = run_sweep(spec, options, progress=not args.no_progress)
    except SweepUnavailable as exc:
        print(f"quadnav-sim sweep: {exc}", file=sys.stderr)
        return EXIT_NO_EXTRA
    except ConnectionError as exc:  # --address: no Ray cluster there
        return _usage(f"--address {args.address}: {exc} (start one with `ray start --head`)")
    except (ConfigError, ValueError, FileNotFoundError) as exc:
        return _usage(str(exc))
    for rec in outcome.records:
        cfg = rec.get("config", {})
        head = f"{rec.get('trial_id', '?'):<14} {cfg.get('name', '')} seed {cfg.get('seed', '?')}"
        if rec["status"] == "ok":
            a, h = rec["eval_all"], rec["eval_held_out"]
            print(
                f"{head}: goal {a['success_rate']:.0%} safe {a['collision_free_rate']:.0%} "
                f"(held-out {h['success_rate']:.0%}) {rec['episodes']} ep, {rec['train_wall_s']} s"
            )
        else:
            print(f"{head}: {rec['status']} {rec.get('error') or ''}".rstrip())
    print(f"tables: {outcome.sweep_json} {outcome.sweep_csv}")
    if outcome.best is not None:
        print(f"best: {outcome.best['model']}\nship it: {outcome.best['ship']}")
    failed = sum(r["status"] == "failed" for r in outcome.records)
    return 1 if failed and failed == len(outcome.records) else 0
