"""``quadnav-sim train``: DQN training per the paper (flags = the fields of TrainConfig).

``--recipe FILE`` reads a YAML mapping of TrainConfig keys (recipes/paper.yaml, recipes/shipped.yaml);
flags given beside it override its keys. Keys map onto TrainConfig by field name, so a field added
to TrainConfig is a recipe key at once; an unknown key, a wrong type or a value out of range is
refused naming the file, the key and the value.

One key is not a field: ``base: OTHER.yaml`` takes every key of another recipe file (a path relative
to the file that names it), the file's own keys overriding them. A recipe that changes one thing of
another is then that one key, not a copy that could drift from it. Bases may chain; a missing base
file or a loop is refused naming the files.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from quadnav_onboard.config import ConfigError, load_yaml_mapping

if TYPE_CHECKING:
    from sim_harness.rl.config import TrainConfig

__all__ = ["add_parser", "config_for", "load_recipe", "run"]


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
    p.add_argument(
        "--recipe",
        metavar="FILE",
        default=None,
        help="YAML file of TrainConfig keys (recipes/paper.yaml, recipes/shipped.yaml); flags override them",
    )
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_dataclass_flags(p, TrainConfig)
    p.set_defaults(func=run)


BASE_KEY = "base"
"""The recipe key naming another recipe file whose keys this one starts from."""

MAX_BASE_DEPTH = 16
"""Longest chain of ``base`` files followed before the chain is refused."""


def _recipe_keys(path: Path, chain: tuple[Path, ...] = ()) -> dict[str, Any]:
    """``path``'s keys over those of its ``base`` chain, each file of the chain validated as a whole
    TrainConfig under its own name (a bad key in a base is reported in the base)."""
    from sim_harness.rl.config import load_train_config

    data = load_yaml_mapping(path)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a mapping of TrainConfig keys, got {type(data).__name__}")
    bad = [k for k in data if not isinstance(k, str)]
    if bad:
        raise ConfigError(f"{path}: key {bad[0]!r}: keys are TrainConfig field names (strings)")
    if BASE_KEY in data:
        base = data.pop(BASE_KEY)
        if not isinstance(base, str) or not base.strip():
            raise ConfigError(
                f"{path}: key {BASE_KEY!r}: bad value {base!r}: the path of another recipe file"
            )
        base_path = (path.parent / base).resolve()
        here = (*chain, path.resolve())
        if base_path in here:
            loop = " -> ".join(str(p) for p in (*here, base_path))
            raise ConfigError(f"{path}: key {BASE_KEY!r}: {base!r} closes a loop of recipe files: {loop}")
        if len(here) >= MAX_BASE_DEPTH:
            raise ConfigError(f"{path}: key {BASE_KEY!r}: more than {MAX_BASE_DEPTH} recipe files chained")
        if not base_path.is_file():
            raise ConfigError(f"{path}: key {BASE_KEY!r}: {base!r}: no such recipe file ({base_path})")
        data = {**_recipe_keys(base_path, here), **data}
    load_train_config(data, source=str(path))
    return data


def load_recipe(path: str | Path) -> dict[str, Any]:
    """A recipe file's keys, its ``base`` chain resolved, validated as a whole TrainConfig (errors
    name the file, key and value)."""
    return _recipe_keys(Path(path))


def config_for(args: argparse.Namespace) -> TrainConfig:
    """The run's config: the recipe file's keys (if any), then the flags given."""
    from sim_harness.rl.config import config_from_args

    base = load_recipe(args.recipe) if getattr(args, "recipe", None) else None
    return config_from_args(args, base=base)


EXIT_INTERRUPTED = 130
"""Exit status after Ctrl-C (128 + SIGINT), the run saved and resumable."""


def run(args: argparse.Namespace) -> int:
    from sim_harness.rl.train import TrainingInterrupted, train
    from sim_harness.world import WorldError

    try:
        if args.resume is not None:
            if args.recipe is not None:
                print(
                    "quadnav-sim train: --resume continues a run with its own config; drop --recipe",
                    file=sys.stderr,
                )
                return 2
            if not (Path(args.resume) / "config.json").is_file():
                print(
                    f"quadnav-sim train: {args.resume}: not a run directory (no config.json)", file=sys.stderr
                )
                return 2
            result = train(resume=args.resume, progress=not args.no_progress)
        else:
            result = train(config_for(args), progress=not args.no_progress)
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
