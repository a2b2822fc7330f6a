"""The dry run's figures, flown as ``quadnav-onboard --dry-run`` flies it: consecutive flights of
Env 1 with the bundled model and the embedded sim config (the flight config's stale-input limits),
the sim's vehicle side in its own processes, each flight in a fresh process.

Figures per flight, and the worst over all:
  * start -> READY (s) and preflight's warm-up (s); the first flight with ``--cold`` runs with an
    empty numba cache (``NUMBA_CACHE_DIR`` in a new directory), as on a fresh machine
  * kernels compiled after arming (goal: none) and whether the flight reached the goal
  * decision latency p99 (goal <= 5 ms in every flight) and setpoint interval p99 (<= 75 ms)
  * daemon CPU, % of one core over the flight (goal <= 25 %): this process only; MAVSDK's
    ``mavsdk_server`` and the record writer (the daemon's other processes) and the sim's parts
    (the vehicle's side) are reported apart

    .venv/bin/python benchmarks/bench_dryrun.py --runs 5 [--cold] [--no-record] --out bench_dryrun.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

GOALS = {"decision_p99_ms": 5.0, "setpoint_interval_p99_ms": 75.0, "daemon_cpu_percent": 25.0}


def _label(cmdline: str) -> str:
    """A child's name: the module it runs (``python -m M``), else its executable."""
    args = cmdline.split("\0")
    if "-m" in args[:-1]:
        return args[args.index("-m") + 1]
    if "resource_tracker" in cmdline:
        return "resource_tracker"
    return Path(args[0]).name


class ChildSampler:
    """CPU seconds of this process's other children (MAVSDK's mavsdk_server, the record's writer
    process), sampled every 0.5 s from /proc while they live: they exit with the flight."""

    def __init__(self, skip: set[int]) -> None:
        self.skip = skip
        self.first: dict[int, tuple[str, float]] = {}
        self.last: dict[int, float] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="bench-sampler", daemon=True)

    def __enter__(self) -> ChildSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        from sim_harness.vehicle_side import process_cpu_s

        while True:
            for task in Path(f"/proc/{os.getpid()}/task").iterdir():
                try:
                    children = [int(c) for c in (task / "children").read_text().split()]
                except OSError:
                    continue
                for pid in children:
                    if pid in self.skip:
                        continue
                    cpu = process_cpu_s(pid)
                    if cpu is None:
                        continue
                    if pid not in self.first:
                        try:
                            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
                        except OSError:
                            continue
                        self.first[pid] = (_label(cmdline), cpu)
                    self.last[pid] = cpu
            if self._stop.wait(0.5):
                return

    def percent(self, wall_s: float) -> dict[str, float]:
        out: dict[str, float] = {}
        for pid, (name, cpu0) in self.first.items():
            key = name if name not in out else f"{name}[{pid}]"
            out[key] = round(100 * (self.last[pid] - cpu0) / wall_s, 1)
        return out


def fly_one(record: bool) -> dict[str, Any]:
    """One dry run in this process, wired as ``quadnav-onboard --dry-run`` wires it."""
    t_start = time.monotonic()
    import dataclasses

    import torch

    from quadnav_onboard.daemon.app import FlightDaemon
    from quadnav_onboard.daemon.config import default_sim_config
    from quadnav_onboard.daemon.dryrun import ProcessDryRun
    from quadnav_onboard.logs import configure_logging
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from quadnav_onboard.record.recorder import FlightRecorder

    configure_logging(json=True, level="warning")
    torch.set_num_threads(1)
    cfg = default_sim_config()
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    with tempfile.TemporaryDirectory(prefix="bench-dryrun-") as rec_dir, ProcessDryRun(cfg) as sim:
        cfg = sim.cfg
        recorder = None
        if record:
            recorder = FlightRecorder.new_in(rec_dir, metadata={"dry_run": "True"},
                                             depth_decimation=cfg.record.depth_decimation,
                                             writer=cfg.record.writer)
        cfg = dataclasses.replace(cfg, record=dataclasses.replace(cfg.record, enabled=record))
        daemon = FlightDaemon(cfg, policy=policy, recorder=recorder, t_start_mono_s=t_start, **sim.parts())
        cpu0, wall0 = time.process_time(), time.monotonic()
        sim0 = sim.side.cpu_s()
        with ChildSampler({part.process.pid for part in sim.side.parts.values()}) as others:
            summary = asyncio.run(daemon.run())
            wall = time.monotonic() - wall0
            cpu = time.process_time() - cpu0
        sim1 = sim.side.cpu_s()
    s = summary.to_dict()
    return {
        "stop_reason": s["stop_reason"],
        "steps": s["steps"],
        "ready_s": s["startup"]["ready_s"],
        "warmup_s": s["startup"]["warmup_s"],
        "kernels_compiled_in_flight": s["startup"]["kernels_compiled_in_flight"],
        "decision_p99_ms": s["decision_latency_ms"]["p99_ms"],
        "decision_max_ms": s["decision_latency_ms"]["max_ms"],
        "setpoint_interval_p99_ms": s["setpoint_interval_ms"]["p99_ms"],
        "daemon_cpu_percent": round(100 * cpu / wall, 1),
        "other_processes_cpu_percent": others.percent(wall),
        "sim_parts_cpu_percent": {k: round(100 * ((sim1.get(k) or 0.0) - (sim0.get(k) or 0.0)) / wall, 1)
                                  for k in sim1},
    }


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--cold", action="store_true", help="the first flight with an empty numba cache")
    p.add_argument("--no-record", action="store_true", help="fly without a flight record")
    p.add_argument("--out", type=Path, default=None, help="write the figures as JSON here")
    p.add_argument("--one", action="store_true", help=argparse.SUPPRESS)  # a single flight, JSON out
    args = p.parse_args()
    if args.one:
        print(json.dumps(fly_one(record=not args.no_record)), flush=True)
        return 0
    flights = []
    for k in range(args.runs):
        env = dict(os.environ)
        cache = None
        if args.cold and k == 0:
            cache = tempfile.mkdtemp(prefix="numba-cold-")
            env["NUMBA_CACHE_DIR"] = cache
        cmd = [sys.executable, __file__, "--one"] + (["--no-record"] if args.no_record else [])
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
        if out.returncode != 0 or not out.stdout.strip():
            print(out.stderr[-3000:], file=sys.stderr)
            raise SystemExit(f"flight {k + 1} failed (exit {out.returncode})")
        fig = json.loads(out.stdout.strip().splitlines()[-1])
        fig["cold"] = cache is not None
        flights.append(fig)
        print(f"flight {k + 1}{' (cold)' if fig['cold'] else ''}: {fig['stop_reason']} after {fig['steps']} "
              f"steps; ready {fig['ready_s']} s (warm-up {fig['warmup_s']} s); decision p99 "
              f"{fig['decision_p99_ms']} ms (max {fig['decision_max_ms']}); setpoint p99 "
              f"{fig['setpoint_interval_p99_ms']} ms; daemon CPU {fig['daemon_cpu_percent']} %; "
              f"others {fig['other_processes_cpu_percent']}; sim {fig['sim_parts_cpu_percent']}; "
              f"compiled in flight {fig['kernels_compiled_in_flight'] or 'none'}", flush=True)
    worst = {key: max(f[key] for f in flights) for key in GOALS}
    met = {key: worst[key] <= goal for key, goal in GOALS.items()}
    met["goal_reached_every_flight"] = all(f["stop_reason"] == "goal_reached" for f in flights)
    met["nothing_compiled_in_flight"] = all(not f["kernels_compiled_in_flight"] for f in flights)
    print("worst: " + ", ".join(f"{k} {v}" for k, v in worst.items()) + f"; goals {GOALS}; met {met}")
    if args.out:
        args.out.write_text(json.dumps({
            "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
            "command": " ".join(sys.argv), "flights": flights, "worst": worst, "goals": GOALS, "met": met,
        }, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
