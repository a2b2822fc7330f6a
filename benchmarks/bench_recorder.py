#!/usr/bin/env python3
"""Recording overhead: how long the control loop spends inside recorder calls, and how late it runs.

Replays a flight's data rates in real time (D435 depth 424x240 at 30 fps, odometry 120 Hz,
setpoints 50 Hz, vehicle state 10 Hz, one decision per second with its 32x32 input) into
:class:`FlightRecorder` and into :class:`NullRecorder`, and reports per call: the time spent in
the call (what the control loop pays) and the lateness of each scheduled call (what the writer's
GIL use costs the loop). Prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_recorder.py --seconds 10 [--writer process|thread] --out OUT.json
"""

from __future__ import annotations

import argparse
import heapq
import json
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from quadnav_onboard.record import FlightRecorder, NullRecorder, read_record

RATES_HZ = {"depth": 30.0, "odometry": 120.0, "setpoint": 50.0, "vehicle": 10.0, "step": 1.0}


def _schedule(seconds: float) -> list[tuple[float, str]]:
    events: list[tuple[float, str]] = []
    for kind, hz in RATES_HZ.items():
        events.extend((k / hz, kind) for k in range(int(seconds * hz)))
    heapq.heapify(events)
    return [heapq.heappop(events) for _ in range(len(events))]


def run(recorder: Any, seconds: float, seed: int = 0) -> dict[str, dict[str, float]]:
    """Feed ``recorder`` for ``seconds`` of real time; return per-kind call/lateness stats (µs)."""
    rng = np.random.default_rng(seed)
    depth = rng.integers(300, 9000, size=(240, 424), dtype=np.uint16)
    inp = rng.random((32, 32), dtype=np.float32)
    q = rng.normal(size=18)
    call_us: dict[str, list[float]] = {k: [] for k in RATES_HZ}
    late_us: list[float] = []
    t_start = time.monotonic() + 0.05
    step = 0
    for t_rel, kind in _schedule(seconds):
        target = t_start + t_rel
        while (now := time.monotonic()) < target:
            time.sleep(min(0.0005, target - now))
        late_us.append((time.monotonic() - target) * 1e6)
        t = time.monotonic()
        c0 = time.perf_counter()
        if kind == "depth":
            recorder.depth(t, depth)
        elif kind == "odometry":
            recorder.odometry(t, [t_rel, 0.0, 2.0], [1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
        elif kind == "setpoint":
            recorder.setpoint(t, [t_rel, 0.0, 2.0], [1.0, 0.0, 0.0], 0.0)
        elif kind == "vehicle":
            recorder.vehicle(t, True, "OFFBOARD", {"local_position_ok": True})
        else:
            recorder.network_input(t, step, inp)
            recorder.step(
                t,
                step=step,
                action=4,
                q_values=q,
                rel_pos_body_m=[1, 0, 0],
                moving_setpoint_world_m=[t_rel, 0, 2],
                pos_world_m=[t_rel, 0, 2],
                reward=0.5,
                reward_terms={"d_now_m": 1.0},
                progress_m=t_rel,
                deviation_m=0.1,
                latency_ms=20.0,
            )
            step += 1
        call_us[kind].append((time.perf_counter() - c0) * 1e6)

    def stats(v: list[float]) -> dict[str, float]:
        a = np.asarray(v)
        return {
            "n": len(a),
            "p50_us": float(np.percentile(a, 50)),
            "p99_us": float(np.percentile(a, 99)),
            "max_us": float(a.max()),
        }

    out = {k: stats(v) for k, v in call_us.items() if v}
    out["lateness"] = stats(late_us)
    return out


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0, help="real time to replay per recorder")
    p.add_argument("--decimation", type=int, default=5, help="raw depth decimation")
    p.add_argument("--out", type=Path, help="write the figures as JSON here")
    p.add_argument(
        "--writer",
        choices=("thread", "process"),
        default="process",
        help="the recorder's writer (default: the daemon's)",
    )
    args = p.parse_args()
    results: dict[str, Any] = {
        "seconds": args.seconds,
        "rates_hz": RATES_HZ,
        "decimation": args.decimation,
        "writer": args.writer,
    }
    results["null"] = run(NullRecorder(), args.seconds)
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.mcap"
        rec = FlightRecorder(
            path, metadata={"bench": "1"}, depth_decimation=args.decimation, writer=args.writer
        )
        results["mcap"] = run(rec, args.seconds)
        t0 = time.perf_counter()
        rec.close("operator_stop", {})
        results["close_s"] = time.perf_counter() - t0
        results["drops"] = rec.drop_counts
        results["file_bytes"] = path.stat().st_size
        results["record_read_ok"] = read_record(path, load_depth=False).complete
    print(f"{'call':<10} {'null p50/p99/max (µs)':>26} {'mcap p50/p99/max (µs)':>26}")
    for kind in [*RATES_HZ, "lateness"]:
        a, b = results["null"][kind], results["mcap"][kind]
        print(
            f"{kind:<10} {a['p50_us']:8.1f} {a['p99_us']:8.1f} {a['max_us']:8.1f} "
            f"{b['p50_us']:8.1f} {b['p99_us']:8.1f} {b['max_us']:8.1f}"
        )
    mb_s = results["file_bytes"] / 1e6 / args.seconds
    print(
        f"file {results['file_bytes'] / 1e6:.1f} MB ({mb_s:.2f} MB/s), drops {results['drops']}, "
        f"close {results['close_s']:.2f} s"
    )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
