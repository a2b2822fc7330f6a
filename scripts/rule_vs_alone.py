#!/usr/bin/env python3
"""Whether the selection rule's score foresees how a checkpoint flies without its filter: pairs
each checkpoint scored by ``quadnav-sim select --json`` with its goals in ``quadnav-sim eval
--shield off --json`` files (matched by the model path each file names), prints the pairs and
Spearman's rank correlation between the rule's score and the alone goals (ties take their mean
rank). A checkpoint scored by the rule but not flown alone, or flown alone but not scored, is
left out and counted.

Usage:  python scripts/rule_vs_alone.py --select SELECT.json [...] --alone EVAL.json [...] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np


def ranks(values: np.ndarray) -> np.ndarray:
    """Ranks from 1, ties given the mean of the ranks they span."""
    order = np.argsort(values, kind="stable")
    r = np.empty(len(values), dtype=float)
    r[order] = np.arange(1, len(values) + 1)
    for v in np.unique(values):
        tied = values == v
        r[tied] = r[tied].mean()
    return r


def spearman(x: np.ndarray, y: np.ndarray) -> float:
    """Spearman's rank correlation: Pearson's on the ranks (nan where either side is constant)."""
    rx, ry = ranks(x), ranks(y)
    if rx.std() == 0 or ry.std() == 0:
        return float("nan")
    return float(np.corrcoef(rx, ry)[0, 1])


def _read(path: str, key: str) -> dict[str, Any]:
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        raise SystemExit(f"rule_vs_alone: {path}: {err}") from None
    if not isinstance(data, dict) or key not in data:
        raise SystemExit(f"rule_vs_alone: {path}: no {key!r}: not the JSON this option takes")
    return data


def pairs(select_files: list[str], alone_files: list[str]) -> tuple[list[dict[str, Any]], int, int]:
    """(model, rule score, alone goals, alone flights) per checkpoint found on both sides, with
    the counts of those scored only and flown only."""
    rule: dict[str, int] = {}
    for f in select_files:
        for s in _read(f, "scores")["scores"]:
            rule[s["model"]] = int(s["score"])
    alone: dict[str, tuple[int, int]] = {}
    for f in alone_files:
        data = _read(f, "rows")
        shield = data.get("shield")
        if not isinstance(shield, dict) or shield.get("enabled") is not False:
            raise SystemExit(f"rule_vs_alone: {f}: flown with the filter; --alone takes --shield off evals")
        rows = data["rows"]
        alone[data["model"]] = (sum(r["outcome"] == "goal" for r in rows), len(rows))
    both = [
        {"model": m, "rule": rule[m], "alone_goals": alone[m][0], "alone_flights": alone[m][1]}
        for m in rule if m in alone
    ]
    return both, len(set(rule) - set(alone)), len(set(alone) - set(rule))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--select", nargs="+", required=True, metavar="JSON",
                    help="quadnav-sim select --json files")
    ap.add_argument("--alone", nargs="+", required=True, metavar="JSON",
                    help="quadnav-sim eval --shield off --json files, one model each")
    ap.add_argument("--json", metavar="OUT", help="write the pairs and the correlation here")
    args = ap.parse_args()
    both, scored_only, flown_only = pairs(args.select, args.alone)
    if len(both) < 3:
        print(f"rule_vs_alone: {len(both)} checkpoints both scored and flown alone; need 3 or more",
              file=sys.stderr)
        return 2
    for p in both:
        print(f"{p['rule']:4d}  {p['alone_goals']:4d} / {p['alone_flights']:<4d} {p['model']}")
    rho = spearman(np.array([p["rule"] for p in both], dtype=float),
                   np.array([p["alone_goals"] for p in both], dtype=float))
    print(f"{len(both)} checkpoints (left out: {scored_only} scored only, {flown_only} flown alone only); "
          f"Spearman's rank correlation of the rule's score and the alone goals: {rho:+.2f}")
    if args.json:
        Path(args.json).write_text(json.dumps({"pairs": both, "spearman": rho, "scored_only": scored_only,
                                               "flown_only": flown_only}, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
