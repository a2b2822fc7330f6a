"""``quadnav-review``: review flight records."""

from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="quadnav-review", description="Review quadnav flight records (MCAP).")
    p.add_argument("records", nargs="+", metavar="RECORD.mcap")
    p.parse_args(argv)
    print("quadnav-review: not yet (issue 7)", file=sys.stderr)
    return 2
