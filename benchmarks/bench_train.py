"""Training-speed benchmark: the paper's 2000-episode budget, wall time, env steps/s, updates/s.

    .venv/bin/python benchmarks/bench_train.py [--episodes 2000] [--json OUT] [extra TrainConfig flags]

Runs ``quadnav-sim train`` in-process with the paper's recipe (defaults of TrainConfig) into a
temporary folder, prints the figures and writes them as JSON. The target: 2000 episodes in
<= 600 s wall on a 2-core CPU. Record the machine load beside the figure: on a shared machine the
figure is pessimistic.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time

from sim_harness.rl.config import add_dataclass_flags, config_from_args
from sim_harness.rl.train import train

TARGET_WALL_S = 600.0


def main(argv: list[str] | None = None) -> int:
    from sim_harness.rl.config import TrainConfig

    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--json", default=None, help="write the figures here")
    add_dataclass_flags(p, TrainConfig)
    args = p.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        if args.out_dir is None:
            args.out_dir = tmp
        if args.name is None:
            args.name = "bench"
        cfg = config_from_args(args)
        load_before = os.getloadavg()[0]
        t0 = time.monotonic()
        result = train(cfg, progress=False)
        wall = time.monotonic() - t0
    out = {
        "benchmark": "train",
        "config": cfg.to_dict(),
        "cpu_count": os.cpu_count(),
        "load_avg_1min_before": round(load_before, 2),
        "load_avg_1min_after": round(os.getloadavg()[0], 2),
        "episodes": result.episodes,
        "env_steps": result.env_steps,
        "updates": result.updates,
        "wall_s": round(wall, 1),
        "env_steps_per_s": round(result.env_steps / wall, 1),
        "updates_per_s": round(result.updates / wall, 1),
        "target_wall_s_for_2000_episodes": TARGET_WALL_S,
        "meets_target": result.episodes >= 2000 and wall <= TARGET_WALL_S,
    }
    print(json.dumps(out, indent=2))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(out, fh, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
