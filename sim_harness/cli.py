"""``quadnav-sim``: worlds, rendering, training, evaluation and the emulated vehicle.

Each subcommand lives in its own module ``sim_harness.cmd_<name>`` exposing
``add_parser(subparsers) -> None`` (which sets ``func`` on its parser) and is listed below.
"""

from __future__ import annotations

import argparse
import importlib
import sys

__all__ = ["main"]

SUBCOMMANDS = ("show", "bench", "train", "sweep", "eval", "route", "select", "serve", "ship", "soup")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="quadnav-sim", description="quadnav simulation harness.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        try:
            module = importlib.import_module(f"sim_harness.cmd_{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"sim_harness.cmd_{name}":
                raise
            continue
        module.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if getattr(args, "func", None) is None:
        parser.print_help()
        return 0
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
