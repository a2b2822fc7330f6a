"""Cost of drawing a minibatch from the replay buffer: uniform against prioritised.

The prioritised buffer draws from the cumulative sum of all priorities (O(capacity) per minibatch,
no sum tree); this prints what that costs beside the gather of the minibatch itself, at the
shipped recipe's sizes (200k transitions, depth and position history 3, batch 256).

    .venv/bin/python benchmarks/bench_replay.py [--capacity 200000] [--batch 256] [--calls 50] [--json OUT]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from sim_harness.rl.replay import PrioritizedReplayBuffer, ReplayBuffer


def _ms(fn, calls: int) -> dict[str, float]:
    fn()  # warm
    t = []
    for _ in range(calls):
        t0 = time.perf_counter()
        fn()
        t.append((time.perf_counter() - t0) * 1e3)
    return {"median_ms": round(float(np.median(t)), 3), "p99_ms": round(float(np.percentile(t, 99)), 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--capacity", type=int, default=200_000)
    ap.add_argument("--batch", type=int, default=256)
    ap.add_argument("--calls", type=int, default=50)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    shapes = (args.capacity, (3, 32, 32), (3, 3))
    uniform, per = ReplayBuffer(*shapes, seed=0), PrioritizedReplayBuffer(*shapes, seed=0)
    for buf in (uniform, per):  # a full buffer; the contents do not change the cost
        buf._size = args.capacity
    per.update_priorities(np.arange(args.capacity), rng.exponential(size=args.capacity))
    figures = {
        "uniform_sample": _ms(lambda: uniform.sample(args.batch), args.calls),
        "prioritized_sample": _ms(lambda: per.sample(args.batch), args.calls),
        "prioritized_cumsum_only": _ms(lambda: np.cumsum(per.priority), args.calls),
        "prioritized_update_priorities": _ms(
            lambda: per.update_priorities(rng.integers(0, args.capacity, args.batch), rng.random(args.batch)),
            args.calls,
        ),
    }
    for name, f in figures.items():
        print(f"{name:32s} median {f['median_ms']:7.3f} ms   p99 {f['p99_ms']:7.3f} ms")
    if args.json:
        out = {"capacity": args.capacity, "batch": args.batch, **figures}
        args.json.write_text(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
