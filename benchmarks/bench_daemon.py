"""The flight daemon's timing figures, with the real MAVSDK against the emulated PX4.

The emulated PX4 runs in its own process (``quadnav-sim serve``), so this process holds only the
daemon: its CPU time is the daemon's. Depth arrives at 30 fps (a pre-rendered 424x240 uint16 frame,
as a camera driver hands it over) and mocap at 120 Hz (PX4's latest pose re-stamped, as a mocap
client would deliver it). Steps are 0.25 s (four times the paper's decision rate) so one run gives
~80 decisions.

Figures:
  * decision latency: step boundary (newest depth frame taken) -> first setpoint of the new
    primitive sent (p99 goal <= 5 ms); with how many decisions found their frame already prepared
    (depth lane run on arrival), waited for its preparation, or prepared it in the step, and the
    frame's age at the step boundary (sensor latency, reported apart)
  * setpoint interval at 20 Hz under that load (p99 goal <= 1.5 x 50 ms = 75 ms)
  * daemon CPU, % of one core (goal <= 25 %), and by thread (loop, DQN executor, native, recorder)
  * stale depth / stale odometry -> hold command issued, after the threshold (goal <= 100 ms)

    .venv/bin/python benchmarks/bench_daemon.py --out bench_daemon.json [--model CKPT.pt] [--record]

``--record``: every flight also writes its MCAP flight record (``FlightRecorder`` with the
daemon's default settings, its writer in a child process), as ``quadnav-onboard`` does unless
``--no-record``; ``--record-writer thread`` writes it from a thread of the flight process instead.
``--switch-interval S`` sets the GIL's switch interval for the daemon (the 1 ms and 0.5 ms trials
of docs/daemon.md and docs/review.md, first run through an ad-hoc wrapper).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import gc
import json
import math
import os
import platform
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import AsyncIterator
from pathlib import Path
from typing import Any

import numpy as np

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import DepthSourceConfig, FlightConfig, MissionConfig, SafetyConfig
from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.logs import configure_logging
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
from quadnav_onboard.sources.base import DepthFrame, OdometrySample
from quadnav_onboard.vehicle import MavsdkVehicle

WORLD = """name: bench
description: a 22 m free path for the daemon benchmark
path: {waypoints: [[0, 0, 1.5], [22, 0, 1.5]], speed_m_s: 1.0}
bounds: {floor_z: 0.0, ceiling_z: 6.0}
obstacles: []
"""


class CameraFeed:
    """30 fps of one pre-rendered frame; ``cut`` stops the feed (cable pulled).

    The frame is the view down the wide corridor of paper Env 2 from 1.5 m, with the sim's
    D435-like noise: a scene, so that the depth safety filter's nearest-surface view sees walls
    and a floor. (Until 2026-12-01 it was uniform noise in 0.5-9 m, which the area-averaged input
    saw as a far wall but the nearest-surface view sees as a wall at 0.5 m on every side.)"""

    def __init__(self, fps: float = 30.0) -> None:
        from sim_harness.noise import DepthNoise
        from sim_harness.render import D435_424x240, render_frame_mm
        from sim_harness.world import load_world, paper_world_path

        self.fps = fps
        world = load_world(paper_world_path(2))
        self.frame = render_frame_mm(
            world, np.array([0.0, 0.0, 1.5]), quat_from_yaw(0.0), D435_424x240, DepthNoise(),
            np.random.default_rng(0),
        )
        self.cut = False

    async def __aenter__(self) -> CameraFeed:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def frames(self) -> AsyncIterator[DepthFrame]:
        t_next, seq = time.monotonic(), 0
        while True:
            t_next += 1.0 / self.fps
            await asyncio.sleep(max(0.0, t_next - time.monotonic()))
            if not self.cut:
                seq += 1
                yield DepthFrame(self.frame.copy(), time.monotonic(), seq)


class MocapFeed:
    """120 Hz samples of the vehicle's latest reported pose; ``cut`` stops the feed."""

    def __init__(self, vehicle: MavsdkVehicle, rate_hz: float = 120.0) -> None:
        self.vehicle, self.rate_hz, self.cut = vehicle, rate_hz, False

    async def __aenter__(self) -> MocapFeed:
        return self

    async def __aexit__(self, *exc: object) -> None:
        return None

    async def samples(self) -> AsyncIterator[OdometrySample]:
        t_next = time.monotonic()
        while True:
            t_next += 1.0 / self.rate_hz
            await asyncio.sleep(max(0.0, t_next - time.monotonic()))
            pos = self.vehicle.state.pos_world_m
            if not self.cut and np.all(np.isfinite(pos)):
                yield OdometrySample(pos.copy(), quat_from_yaw(0.0), time.monotonic())


def cpu_seconds(stat: Path) -> float:
    """utime + stime (s) of a process or thread, from its /proc ``stat`` file."""
    fields = stat.read_text().rsplit(")", 1)[1].split()  # the name may hold spaces; it ends at ')'
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class ThreadCpu:
    """CPU time of each thread of this process over a flight, by thread name (Python threads by
    their ``threading`` name, native ones, such as MAVSDK's, as ``native``), from
    ``/proc/self/task/*/stat`` sampled every 0.25 s: a thread that ends between samples keeps its
    last sample."""

    def __init__(self) -> None:
        self.first: dict[int, float] = self._read()
        self.last: dict[int, float] = dict(self.first)
        self.names: dict[int, str] = {}

    @staticmethod
    def _read() -> dict[int, float]:
        out = {}
        for task in Path("/proc/self/task").iterdir():
            with contextlib.suppress(OSError, ValueError):
                out[int(task.name)] = cpu_seconds(task / "stat")
        return out

    def sample(self) -> None:
        self.last.update(self._read())
        self.names.update({t.native_id: t.name for t in threading.enumerate() if t.native_id is not None})

    async def run(self) -> None:
        while True:
            self.sample()
            await asyncio.sleep(0.25)

    def fractions(self, wall_s: float) -> dict[str, float]:
        """Fraction of one core per thread name over ``wall_s``, largest first."""
        by_name: dict[str, float] = {}
        for tid, c in self.last.items():
            name = self.names.get(tid, "native")
            by_name[name] = by_name.get(name, 0.0) + (c - self.first.get(tid, 0.0)) / wall_s
        return {k: round(v, 4) for k, v in sorted(by_name.items(), key=lambda kv: -kv[1]) if v > 0}


def config(max_steps: int, prepare_every_frame: bool = False) -> FlightConfig:
    depth = DepthSourceConfig(prepare_within_s=None) if prepare_every_frame else DepthSourceConfig()
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=max_steps, land_at_goal=False),
        primitives=parse_config(PrimitiveConfig, {"scale_m": 0.25, "duration_s": 0.25}),
        safety=SafetyConfig(land_on_abort=False, hold_before_land_s=0.0),
        depth=depth,
    )


async def fly(
    port: int,
    policy: Policy,
    max_steps: int,
    cut: str | None,
    record: Path | None = None,
    writer: str | None = None,
    full_gc: bool = False,
    prepare_every_frame: bool = False,
) -> tuple[Any, float, float | None, dict[str, float]]:
    """Fly one benchmark flight; returns its summary, the daemon's CPU, the record writer
    process's CPU (fractions of one core; None without a writer process) and the daemon's CPU by
    thread (:class:`ThreadCpu`)."""
    vehicle = MavsdkVehicle(f"udpin://127.0.0.1:{port}", connect_timeout_s=15.0)
    depth, mocap = CameraFeed(), MocapFeed(vehicle)
    path = RoughPath(np.array([[0.0, 0.0, 1.5], [22.0, 0.0, 1.5]]), 1.0)
    cfg = config(max_steps, prepare_every_frame)
    recorder = None
    if record is not None:
        from quadnav_onboard.record import FlightRecorder

        recorder = FlightRecorder(
            record,
            metadata={"benchmark": "bench_daemon"},
            depth_decimation=cfg.record.depth_decimation,
            writer=cfg.record.writer if writer is None else writer,
        )
    daemon = FlightDaemon(
        cfg, path=path, policy=policy, depth=depth, odometry=mocap, vehicle=vehicle, recorder=recorder
    )

    async def cutter() -> None:
        while not (daemon.in_mission and daemon.steps >= 4):
            await asyncio.sleep(0.01)
        (depth if cut == "depth" else mocap).cut = True

    task = asyncio.ensure_future(cutter()) if cut else None

    async def full_collection() -> None:  # as the interpreter would run one, on the loop's thread
        while not (daemon.in_mission and daemon.steps >= 40):
            await asyncio.sleep(0.01)
        gc.collect()

    collector = asyncio.ensure_future(full_collection()) if full_gc else None
    writer_pid = recorder.writer_pid if recorder is not None else None
    writer_cpu: list[tuple[float, float]] = []

    async def sample_writer_cpu() -> None:  # the record's writer process, while it lives
        while writer_pid is not None:
            try:
                writer_cpu.append((time.monotonic(), cpu_seconds(Path(f"/proc/{writer_pid}/stat"))))
            except OSError:
                return
            await asyncio.sleep(0.25)

    sampler = asyncio.ensure_future(sample_writer_cpu())
    threads = ThreadCpu()
    thread_sampler = asyncio.ensure_future(threads.run())
    cpu0, wall0 = time.process_time(), time.monotonic()
    summary = await daemon.run()
    wall = time.monotonic() - wall0
    cpu = (time.process_time() - cpu0) / wall
    threads.sample()
    for t in (sampler, thread_sampler):
        t.cancel()
    for t in (task, collector):
        if t is not None:
            t.cancel()
    writer_frac = None
    if len(writer_cpu) >= 2:
        (t0, c0), (t1, c1) = writer_cpu[0], writer_cpu[-1]
        writer_frac = (c1 - c0) / (t1 - t0)
        print(f"record writer process CPU: {100 * writer_frac:.1f} % of one core (sampled)")
    return summary, cpu, writer_frac, threads.fractions(wall)


def serve(world: Path, port: int) -> subprocess.Popen[bytes]:
    cmd = [
        sys.executable,
        "-m",
        "sim_harness.cli",
        "serve",
        "--world",
        str(world),
        "--api-port",
        str(port),
        "--gcs-port",
        "0",
        "--heartbeat-hz",
        "10",
    ]
    return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


class GcPauses:
    """Times every garbage collection of this process (``gc.callbacks``): a full collection over
    the objects torch, numpy and MAVSDK leave on the heap is a candidate for a decision's tail."""

    def __init__(self) -> None:
        self.pauses: list[tuple[int, float, float]] = []
        self._t0 = 0.0
        self._created = time.perf_counter()
        gc.callbacks.append(self._cb)

    def _cb(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._t0 = time.perf_counter()
        else:
            t = time.perf_counter()
            self.pauses.append((info["generation"], (t - self._t0) * 1e3, self._t0 - self._created))

    def close(self) -> None:
        gc.callbacks.remove(self._cb)

    def summary(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for gen in (0, 1, 2):
            ms = [p for g, p, _ in self.pauses if g == gen]
            out[f"gen{gen}"] = {"count": len(ms), "max_ms": round(max(ms, default=0.0), 3)}
        out["gen2_at_s_ms"] = [(round(t, 2), round(p, 2)) for g, p, t in self.pauses if g == 2]
        out["over_1ms"] = sum(p > 1.0 for _, p, _ in self.pauses)
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--model", type=Path, default=None, help="checkpoint (default: bundled, else a test model)"
    )
    ap.add_argument("--stale-runs", type=int, default=3, help="runs per stale-input reaction figure")
    ap.add_argument("--out", type=Path, default=Path("bench_daemon.json"))
    ap.add_argument("--record", action="store_true", help="write each flight's MCAP record (as in flight)")
    ap.add_argument(
        "--record-writer",
        choices=("process", "thread"),
        default=None,
        help="where the record is written (default: the daemon's, RecordConfig.writer)",
    )
    ap.add_argument(
        "--no-gc-freeze", action="store_true", help="skip the daemon's heap freeze (to measure what it buys)"
    )
    ap.add_argument(
        "--full-gc-mid-flight",
        action="store_true",
        help="run one full garbage collection at step 40 of the main flight, on the daemon's thread, "
        "as the interpreter may at any time (its pause is in gc_pauses_main_run)",
    )
    ap.add_argument(
        "--prepare-every-frame",
        action="store_true",
        help="depth.prepare_within_s: null, every frame prepared on arrival (the daemon before that key)",
    )
    ap.add_argument(
        "--switch-interval",
        type=float,
        default=None,
        metavar="S",
        help="sys.setswitchinterval(S) for the daemon's process (Python's default 0.005 s): how soon a "
        "thread that holds the GIL hands it over",
    )
    args = ap.parse_args()
    if args.switch_interval is not None:
        if not args.switch_interval > 0:
            ap.error(f"--switch-interval: must be > 0 s, got {args.switch_interval}")
        sys.setswitchinterval(args.switch_interval)
    if args.no_gc_freeze:
        import quadnav_onboard.daemon.app as app

        app.freeze_heap = lambda: None
    configure_logging(json=True, level="error")
    import torch

    torch.set_num_threads(1)
    tmp = Path(tempfile.mkdtemp(prefix="bench_daemon_"))
    model = args.model or (DEFAULT_MODEL_PATH if DEFAULT_MODEL_PATH.exists() else None)
    if model is None:
        model = tmp / "forward.pt"
        constant_action_checkpoint(str(model), 4)
    policy = Policy.from_path(model)
    world = tmp / "world.yaml"
    world.write_text(WORLD)
    from sim_harness.px4 import free_udp_port

    results: dict[str, Any] = {
        "machine": platform.platform(),
        "cpus": os.cpu_count(),
        "model": str(model),
        "loadavg_at_start": [round(x, 2) for x in os.getloadavg()],
        "recording": args.record,
        "gc_freeze": not args.no_gc_freeze,
        "full_gc_mid_flight": args.full_gc_mid_flight,
        "switch_interval_s": sys.getswitchinterval(),
        "prepare_within_s": config(1, args.prepare_every_frame).depth.prepare_within_s,
        "record_writer": (args.record_writer or FlightConfig().record.writer) if args.record else None,
    }
    stale: dict[str, list[float]] = {"depth": [], "odometry": []}
    runs = [("main", None)] + [(k, k) for k in ("depth", "odometry") for _ in range(args.stale_runs)]
    for i, (name, cut) in enumerate(runs):
        port = free_udp_port()
        emu = serve(world, port)
        record = tmp / f"flight-{i}-{name}.mcap" if args.record else None
        try:
            steps = 80 if cut is None else 30
            gc_pauses = GcPauses() if cut is None else None
            full_gc = args.full_gc_mid_flight and cut is None
            summary, cpu, writer_cpu, thread_cpu = asyncio.run(
                fly(port, policy, steps, cut, record, args.record_writer, full_gc, args.prepare_every_frame)
            )
            if gc_pauses is not None:
                gc_pauses.close()
                results["gc_pauses_main_run"] = gc_pauses.summary()
        finally:
            emu.terminate()
            emu.wait(10)
        if cut is None:
            results["main_run"] = {
                **summary.to_dict(),
                "daemon_cpu_fraction_of_one_core": round(cpu, 4),
                "daemon_cpu_by_thread_fraction_of_one_core": thread_cpu,
            }
            if writer_cpu is not None:
                results["main_run"]["record_writer_cpu_fraction_of_one_core"] = round(writer_cpu, 4)
            if record is not None:
                results["main_run"]["record_bytes"] = record.stat().st_size
        elif summary.hold_reaction_ms is not None:
            stale[cut].append(summary.hold_reaction_ms)
        print(f"{name}: stop {summary.stop_reason}, steps {summary.steps}, cpu {cpu:.1%}", flush=True)
    results["loadavg_at_end"] = [round(x, 2) for x in os.getloadavg()]
    main_run = results["main_run"]
    results["stale_to_hold_ms"] = {k: v for k, v in stale.items()}
    figures = {
        "decision_latency_p99_ms": main_run["decision_latency_ms"]["p99_ms"],
        "setpoint_interval_p99_ms": main_run["setpoint_interval_ms"]["p99_ms"],
        "daemon_cpu_percent_of_one_core": round(100 * main_run["daemon_cpu_fraction_of_one_core"], 1),
        "stale_depth_to_hold_max_ms": max(stale["depth"], default=math.nan),
        "stale_odometry_to_hold_max_ms": max(stale["odometry"], default=math.nan),
    }
    goals = {
        "decision_latency_p99_ms": 5.0,
        "setpoint_interval_p99_ms": 75.0,
        "daemon_cpu_percent_of_one_core": 25.0,
        "stale_depth_to_hold_max_ms": 100.0,
        "stale_odometry_to_hold_max_ms": 100.0,
    }
    results["figures"], results["goals"] = figures, goals
    results["decisions"] = {  # no goal: how the decisions ran, and the sensor latency apart
        "prepared": main_run["decision_paths"]["prepared"],
        "waited": main_run["decision_paths"]["waited"],
        "full": main_run["decision_paths"]["full"],
        "depth_frames": main_run["depth_frames"],
        "decision_latency_p50_ms": main_run["decision_latency_ms"]["p50_ms"],
        "decision_latency_max_ms": main_run["decision_latency_ms"]["max_ms"],
        "frame_age_p50_ms": main_run["frame_age_ms"]["p50_ms"],
        "frame_age_p99_ms": main_run["frame_age_ms"]["p99_ms"],
    }
    print(f"\n{'figure':36s} {'measured':>10s} {'goal':>8s}")
    for k, v in figures.items():
        ok = "ok" if v is not None and v <= goals[k] else "MISSED"
        print(f"{k:36s} {v!s:>10s} {goals[k]:8.1f}  {ok}")
    lat, dqn = main_run["decision_latency_ms"], main_run["inference_ms"]
    age, paths = main_run["frame_age_ms"], main_run["decision_paths"]
    print(
        f"\ndecision latency p50 {lat['p50_ms']} / p99 {lat['p99_ms']} / max {lat['max_ms']} ms; "
        f"DQN work at the step p50 {dqn['p50_ms']} / p99 {dqn['p99_ms']} ms"
    )
    print("decisions: {prepared} prepared on arrival, {waited} waited, {full} full".format(**paths))
    print("depth frames: {received} received, {prepared} prepared, {checked} only checked".format(
        **main_run["depth_frames"]))
    print("daemon CPU by thread, % of one core: " + ", ".join(
        f"{k} {100 * v:.1f}" for k, v in main_run["daemon_cpu_by_thread_fraction_of_one_core"].items()))
    print(f"setpoint interval max {main_run['setpoint_interval_ms']['max_ms']} ms")
    print(f"frame age at the step (sensor latency): p50 {age['p50_ms']} / p99 {age['p99_ms']} ms")
    print(f"load average at start {results['loadavg_at_start']}, at end {results['loadavg_at_end']}")
    print(f"garbage collections during the main flight: {results['gc_pauses_main_run']}")
    if args.record:
        print(f"recording on: main flight's record {results['main_run']['record_bytes'] / 1e6:.1f} MB")
    args.out.write_text(json.dumps(results, indent=2, default=str))
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
