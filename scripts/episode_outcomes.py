#!/usr/bin/env python3
"""How a training run's episodes ended, per world, over a range of episodes (from its metrics).

For reading what an ε-greedy agent sees while it learns: mean progress along the path, and the
shares of episodes that reached the goal or crashed.

Usage:  python scripts/episode_outcomes.py RUN_DIR [--from E0] [--to E1] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

from sim_harness.rl.runlog import read_metrics


def outcomes(rows: list[dict], first: int, last: int | None) -> dict[str, dict[str, float]]:
    """Per world: episodes, mean progress (m), goal and crash shares, over episodes [first, last)."""
    by_world: dict[str, list[dict]] = defaultdict(list)
    for r in rows:
        if r["episode"] >= first and (last is None or r["episode"] < last):
            by_world[r["world"]].append(r)
    out = {}
    for world, rs in sorted(by_world.items()):
        n = len(rs)
        out[world] = {
            "episodes": n,
            "mean_progress_m": round(sum(r["progress_m"] for r in rs) / n, 2),
            "goal_share": round(sum(r["outcome"] == "goal" for r in rs) / n, 3),
            "crash_share": round(sum(r["outcome"] == "crash" for r in rs) / n, 3),
        }
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--from", dest="first", type=int, default=0, help="first episode (default 0)")
    ap.add_argument("--to", dest="last", type=int, default=None, help="episode after the last (default: all)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rows = read_metrics(args.run_dir)
    if not rows:
        print(f"episode_outcomes: no metrics.json in {args.run_dir}", file=sys.stderr)
        return 2
    table = outcomes(rows, args.first, args.last)
    print(f"{'world':28s} {'episodes':>8s} {'progress m':>10s} {'goal':>6s} {'crash':>6s}")
    for world, f in table.items():
        print(
            f"{world:28s} {f['episodes']:8d} {f['mean_progress_m']:10.1f} "
            f"{f['goal_share']:6.0%} {f['crash_share']:6.0%}"
        )
    if args.json:
        args.json.write_text(json.dumps(table, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
