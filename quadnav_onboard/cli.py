"""``quadnav-onboard``: the flight daemon's command line."""

from __future__ import annotations

import argparse
import sys

__all__ = ["main"]


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadnav-onboard",
        description="Fly a quadrotor with the quadnav DQN planner through PX4 (MAVSDK offboard).",
    )
    p.add_argument("--config", metavar="FLIGHT.yaml", help="flight configuration (see config/flight.yaml)")
    p.add_argument("--dry-run", action="store_true", help="fly in the sim harness with the bundled model")
    p.add_argument("--world", metavar="WORLD.yaml", help="with --dry-run: world file to fly (default: Env 1)")
    p.add_argument("--json", action="store_true", help="print the flight summary as one JSON object")
    return p


def main(argv: list[str] | None = None) -> int:
    build_parser().parse_args(argv)
    print("quadnav-onboard: the flight daemon is not built yet (issue 6)", file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())
