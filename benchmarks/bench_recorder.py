#!/usr/bin/env python3
"""Recording overhead: how long the control loop spends inside recorder calls, and how late it runs.

Replays a flight's data rates in real time (D435 depth 424x240 at 30 fps, odometry 120 Hz,
setpoints 50 Hz, vehicle state 10 Hz, one decision per second with its 32x32 input) into
:class:`FlightRecorder` and into :class:`NullRecorder`, and reports per call: the time spent in
the call (what the control loop pays) and the lateness of each scheduled call (what the writer's
GIL use costs the loop). Then, apart from the replay, the writer's own cost per depth frame and
per step (encode and write into the MCAP file, CPU µs, as the writer process pays it) and the
record's size per flight minute. Prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_recorder.py --seconds 10 [--writer process|thread] \
        [--depth random|scene] --out OUT.json

``--depth random`` (default) replays incompressible frames (uniform 0.3-9 m), ``scene`` plausible
ones (``quadnav_onboard.record.synthetic``: open space, floor, a box). The script runs against an
older version of the package too (``PYTHONPATH=<a checkout of it>``), leaving out what that version
does not record (the step's primitive, the camera), so figures before and after a change come from
this one command.
"""

from __future__ import annotations

import argparse
import heapq
import inspect
import json
import resource
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.record import FlightRecorder, NullRecorder, read_record
from quadnav_onboard.record.sink import McapSink
from quadnav_onboard.record.synthetic import _depth_frame

DRAWS_PRIMITIVES = "primitive" in inspect.signature(FlightRecorder.step).parameters
"""This version of the recorder takes the step's primitive (and the camera)."""
TAKES_STEP_RECORD = hasattr(FlightRecorder, "step_record")
"""This version records the core's typed StepRecord (``FlightRecorder.step_record``), as the daemon
calls it; older ones take the step's fields as keywords (``FlightRecorder.step``)."""


@dataclass(frozen=True)
class Commanded:
    """A commanded primitive, as the daemon's ActivePrimitive hands it to the recorder."""

    primitives: PrimitiveSet
    start_world_m: np.ndarray
    start_vel_world_m_s: np.ndarray
    yaw_rad: float


PRIMS = PrimitiveSet()


def _depth(kind: str, rng: np.random.Generator) -> np.ndarray:
    if kind == "scene":
        return _depth_frame(np.array([6.0, 0.0, 2.0]), rng)
    return rng.integers(300, 9000, size=(240, 424), dtype=np.uint16)


def _decision(step: int, t_rel: float, q: np.ndarray) -> dict[str, Any]:
    """One step's recorder arguments (with its primitive when this recorder draws them)."""
    d: dict[str, Any] = dict(
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
        shield_allowed=np.arange(18) % 4 != 0,
        shield_clearance_m=np.linspace(0.2, 1.5, 18),
    )
    if DRAWS_PRIMITIVES:
        d["primitive"] = Commanded(PRIMS, np.array([t_rel, 0.0, 2.0]), np.array([1.0, 0.0, 0.0]), 0.0)
    return d

def _step_record(step: int, t_rel: float, q: np.ndarray) -> Any:
    """One step as the core's StepRecord (N = 1), with the same values as :func:`_decision`."""
    from quadnav_onboard.step import StepRecord

    one = lambda v, dtype=np.float64: np.array([v], dtype=dtype)  # noqa: E731
    return StepRecord(
        step=one(step, np.int64), action=one(4, np.int64), q_values=q[None, :].copy(),
        rel_pos_body_m=one([1.0, 0.0, 0.0]), moving_setpoint_world_m=one([t_rel, 0.0, 2.0]),
        pos_world_m=one([t_rel, 0.0, 2.0]), yaw_rad=one(0.0), end_pos_world_m=one([t_rel + 1.0, 0.0, 2.0]),
        d_prev_m=one(1.0), d_now_m=one(1.0), progress_m=one(t_rel), deviation_m=one(0.1),
        deviated=one(False, np.bool_), collided=one(False, np.bool_), reward=one(0.5),
        outcome=one(0, np.int8), shield_allowed=(np.arange(18) % 4 != 0)[None, :],
        shield_clearance_m=np.linspace(0.2, 1.5, 18)[None, :],
    )


def _call_step(recorder: Any, t: float, step: int, decision: dict[str, Any], record: Any) -> None:
    """Record one step the way this version's daemon does."""
    if TAKES_STEP_RECORD:
        prim = decision.get("primitive")
        recorder.step_record(t, record, latency_ms=decision["latency_ms"], primitive=prim)
    else:
        recorder.step(t, **decision)


RATES_HZ = {"depth": 30.0, "odometry": 120.0, "setpoint": 50.0, "vehicle": 10.0, "step": 1.0}


def _schedule(seconds: float) -> list[tuple[float, str]]:
    events: list[tuple[float, str]] = []
    for kind, hz in RATES_HZ.items():
        events.extend((k / hz, kind) for k in range(int(seconds * hz)))
    heapq.heapify(events)
    return [heapq.heappop(events) for _ in range(len(events))]


def run(
    recorder: Any, seconds: float, seed: int = 0, depth_kind: str = "random"
) -> dict[str, dict[str, float]]:
    """Feed ``recorder`` for ``seconds`` of real time; return per-kind call/lateness stats (µs)."""
    rng = np.random.default_rng(seed)
    depth = _depth(depth_kind, rng)
    inp = rng.random((32, 32), dtype=np.float32)
    q = rng.normal(size=18)
    call_us: dict[str, list[float]] = {k: [] for k in RATES_HZ}
    late_us: list[float] = []
    t_start = time.monotonic() + 0.05
    step = 0
    decision = _decision(step, 0.0, q)  # built outside the timed call, as the daemon does
    record = _step_record(step, 0.0, q) if TAKES_STEP_RECORD else None
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
            _call_step(recorder, t, step, decision, record)
        call_us[kind].append((time.perf_counter() - c0) * 1e6)
        if kind == "step":
            step += 1
            decision = _decision(step, t_rel + 1.0, q)
            record = _step_record(step, t_rel + 1.0, q) if TAKES_STEP_RECORD else None

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


def writer_cost(depth_kind: str, n_depth: int = 200, n_steps: int = 1000) -> dict[str, dict[str, float]]:
    """The writer's CPU (µs) per depth frame and per step (its messages encoded and written into
    an MCAP file, chunks compressed), and bytes written per item."""
    rng = np.random.default_rng(1)
    depth = _depth(depth_kind, rng)
    q = rng.normal(size=18)
    options = {
        "metadata": {"bench": "1"},
        "depth_decimation": 1,
        "unix_minus_mono_s": time.time() - time.monotonic(),
        "chunk_size": 256 * 1024,
        "fsync": False,
        "flush_interval_s": 1.0,
    }
    out = {}
    kinds = [("depth", n_depth, True), ("step", n_steps, True)]
    if DRAWS_PRIMITIVES:  # the step record alone, as the previous format recorded it
        kinds.append(("step", n_steps, False))
    for kind, n, drawn in kinds:
        with tempfile.TemporaryFile() as f:
            sink = McapSink.from_options(f, options)
            if DRAWS_PRIMITIVES:
                sink.write("primitive_set", 1.0, PRIMS)
            start = f.tell()
            items = [
                (kind, 1.0 + i * 0.01, depth if kind == "depth" else _decision(i, float(i), q))
                for i in range(n)
            ]
            if kind == "step":  # what the recorder queues, as the writer receives it
                items = [(k, t, _as_queued(d, drawn, i, q)) for i, (k, t, d) in enumerate(items)]
            c0 = time.process_time()
            for item in items:
                sink.write(*item)
            sink.flush()
            cpu = time.process_time() - c0
            name = kind if drawn else "step_record_alone"
            out[name] = {"n": n, "cpu_us": cpu / n * 1e6, "bytes": (f.tell() - start) / n}
    return out


def _as_queued(d: dict[str, Any], drawn: bool, step: int, q_values: np.ndarray) -> Any:
    """The step the recorder queues: (StepRecord, latency, primitive) or, in older versions, the
    keyword dict; the primitive reduced to start, velocity and heading."""
    out = dict(d)
    prim = out.pop("primitive", None) if drawn else None
    reduced = (prim.start_world_m, prim.start_vel_world_m_s, prim.yaw_rad) if prim else None
    if TAKES_STEP_RECORD:
        return (_step_record(step, float(step), q_values), d["latency_ms"], reduced)
    if DRAWS_PRIMITIVES:
        out["primitive"] = reduced
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
    p.add_argument("--depth", choices=("random", "scene"), default="random", help="depth frames replayed")
    p.add_argument(
        "--writer-cost-only", action="store_true", help="measure only the writer's cost per item (no replay)"
    )
    args = p.parse_args()
    if args.writer_cost_only:
        cost = writer_cost(args.depth)
        for kind, c in cost.items():
            print(f"writer, per {kind}: {c['cpu_us']:.0f} µs CPU, {c['bytes'] / 1e3:.1f} kB written")
        if args.out:
            args.out.parent.mkdir(parents=True, exist_ok=True)
            args.out.write_text(json.dumps({"depth": args.depth, "writer_cost": cost}, indent=2))
        return 0
    results: dict[str, Any] = {
        "seconds": args.seconds,
        "rates_hz": RATES_HZ,
        "decimation": args.decimation,
        "writer": args.writer,
        "depth": args.depth,
        "draws_primitives": DRAWS_PRIMITIVES,
        "takes_step_record": TAKES_STEP_RECORD,
    }
    c0 = time.process_time()
    results["null"] = run(NullRecorder(), args.seconds, depth_kind=args.depth)
    null_cpu_s = time.process_time() - c0
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "bench.mcap"
        rec = FlightRecorder(
            path, metadata={"bench": "1"}, depth_decimation=args.decimation, writer=args.writer
        )
        if DRAWS_PRIMITIVES:
            rec.camera(time.monotonic(), width_px=424, height_px=240, hfov_deg=87.0, vfov_deg=58.0)
        c0, child0 = time.process_time(), resource.getrusage(resource.RUSAGE_CHILDREN)
        results["mcap"] = run(rec, args.seconds, depth_kind=args.depth)
        t0 = time.perf_counter()
        rec.close("operator_stop", {})
        results["close_s"] = time.perf_counter() - t0
        child1 = resource.getrusage(resource.RUSAGE_CHILDREN)  # the writer process, waited for at close
        results["cpu_percent_of_a_core"] = {
            "flight_process_recorder": 100 * (time.process_time() - c0 - null_cpu_s) / args.seconds,
            "writer_process": 100 * (child1.ru_utime + child1.ru_stime - child0.ru_utime - child0.ru_stime)
            / args.seconds,
        }
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
    results["mb_per_flight_minute"] = mb_s * 60
    print(
        f"file {results['file_bytes'] / 1e6:.1f} MB ({mb_s:.2f} MB/s, {mb_s * 60:.0f} MB per flight minute), "
        f"drops {results['drops']}, close {results['close_s']:.2f} s"
    )
    cpu = results["cpu_percent_of_a_core"]
    print(
        f"CPU, % of a core: the recorder in the flight process {cpu['flight_process_recorder']:.1f} "
        f"(FlightRecorder run minus NullRecorder run), writer process {cpu['writer_process']:.1f}"
    )
    results["writer_cost"] = writer_cost(args.depth)
    for kind, c in results["writer_cost"].items():
        print(f"writer, per {kind}: {c['cpu_us']:.0f} µs CPU, {c['bytes'] / 1e3:.1f} kB written")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
