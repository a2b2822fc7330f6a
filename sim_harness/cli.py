"""``quadnav-sim``: worlds, rendering, training, evaluation and the emulated vehicle."""

from __future__ import annotations

import argparse

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="quadnav-sim", description="quadnav simulation harness.")
    p.add_subparsers(dest="command")
    args = p.parse_args(argv)
    if args.command is None:
        p.print_help()
    return 0
