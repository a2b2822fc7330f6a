"""Render benchmark: prints figures and writes JSON (``--json PATH``).

    .venv/bin/python benchmarks/bench_render.py [--seconds 2] [--json out/bench_render.json]

The measurement lives in :func:`sim_harness.cmd_bench.run_render` so that ``quadnav-sim bench``
runs the same code.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from sim_harness.cmd_bench import _print_render, run_render


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="time per measurement (s)")
    ap.add_argument("--batch", type=int, default=4096, help="poses per 32x32 render call")
    ap.add_argument("--threads", type=int, default=None, help="numba threads (default: all cores)")
    ap.add_argument("--json", metavar="PATH", help="write the figures as JSON to PATH")
    args = ap.parse_args()
    result = run_render(args.seconds, args.batch, threads=args.threads)
    _print_render(result)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
