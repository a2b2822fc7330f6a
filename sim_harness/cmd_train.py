"""``quadnav-sim train``: DQN training per the paper (flags = the fields of TrainConfig)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from quadnav_onboard.config import ConfigError

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    from sim_harness.rl.config import TrainConfig, add_dataclass_flags

    p = subparsers.add_parser(
        "train",
        help="train the DQN (the paper's recipe; options beyond it are flags)",
        description="Train the DQN. Every flag is a TrainConfig field; the run directory holds the "
        "config, metrics (CSV/JSON), checkpoints and the reward curve.",
    )
    p.add_argument(
        "--resume", metavar="RUN_DIR", default=None, help="continue a killed run from its last checkpoint"
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_dataclass_flags(p, TrainConfig)
    p.set_defaults(func=run)


EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), the run saved and resumable."""


def run(args: argparse.Namespace) -> int:
    from sim_harness.rl.config import config_from_args
    from sim_harness.rl.train import TrainingInterrupted, train
    from sim_harness.world import WorldError

    try:
        if args.resume is not None:
            if not (Path(args.resume) / "config.json").is_file():
                print(
                    f"quadnav-sim train: {args.resume}: not a run directory (no config.json)", file=sys.stderr
                )
                return 2
            result = train(resume=args.resume, progress=not args.no_progress)
        else:
            result = train(config_from_args(args), progress=not args.no_progress)
    except (ConfigError, WorldError) as exc:
        print(f"quadnav-sim train: {exc}", file=sys.stderr)
        return 2
    except TrainingInterrupted as stop:
        r = stop.result
        print(
            f"quadnav-sim train: interrupted after {r.episodes} episodes; saved {r.model_path}\n"
            f"resume with: quadnav-sim train --resume {r.run_dir}",
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    except KeyboardInterrupt:
        print("quadnav-sim train: interrupted before the first episode; nothing was trained", file=sys.stderr)
        return EXIT_INTERRUPTED
    print(f"run directory: {result.run_dir}")
    print(f"model:         {result.model_path}")
    print(
        f"episodes {result.episodes}, env steps {result.env_steps}, updates {result.updates}, "
        f"wall {result.wall_s:.1f} s, {result.env_steps_per_s:.0f} env steps/s, "
        f"{result.updates_per_s:.1f} updates/s"
    )
    return 0
