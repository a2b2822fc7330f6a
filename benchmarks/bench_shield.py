"""Cost of the depth safety filter per frame, as the daemon pays it.

For each filter variant: ``Decider.prepare`` on one frame (preprocessing, depth lane and the filter's
verdict against a full memory), the shipped model, one torch thread. The frame is the one
``bench_daemon.py`` streams (the sim's noisy view down Env 2's corridor); the memory is filled with
that frame seen from points 0.25 m apart along the path, as in a flight.

    .venv/bin/python benchmarks/bench_shield.py [--scale 0.5] [--calls 300] [--json OUT]

Prints median and p99 (ms) per variant, and the median of the filter's verdict alone
(``shield_verdict`` on the full memory): the first filter (area-averaged view, no shadows, no
floor), the shipped one, the shipped one without forgetting seen-through shadows, the shipped one
looking ahead along the stop (``lookahead: stop``), and no filter.

    .venv/bin/python benchmarks/bench_shield.py --flights [--scale 0.5] [--trials 1] [--json OUT]

``--flights`` times the verdict where the corridor scene above cannot: in real evaluation flights
(the shipped model over Env 1-7, eval seed 0, one vehicle per call as in the daemon), every call
of ``shield_verdict`` the sim makes, with the memory the scale implies (8 decisions at 0.5 m) and
with the 4 decisions it kept at first. Flights may differ between the two (the filter may allow
different moves), so each line also says how many calls and goals it timed.

    .venv/bin/python benchmarks/bench_shield.py --starvation [--scale 0.5] [--json OUT]

``--starvation`` checks whether preparing frames starves another thread of the GIL, as the
daemon's loop would be: a thread runs ``Decider.prepare`` 30 times a second (the D435's rate)
while the main thread sleeps 2 ms, 3000 times; it prints how much each sleep overran (p50, p99,
max), for the first filter and the shipped one, and with no preparing thread at all.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_daemon import CameraFeed

from quadnav_onboard.daemon.decide import FLOOR_Z_M, Decider, Motion
from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.shield import ShieldConfig, shield_config_from_meta, shield_verdict
from quadnav_onboard.sources.base import DepthFrame


def _motion(x: float) -> Motion:
    p = np.array([x, 0.0, 1.5])
    return Motion(p, np.zeros(3), p.copy(), np.zeros(3), 0.0)


def first_filter(shipped: ShieldConfig) -> ShieldConfig:
    """The filter's first version: area-averaged view, no shadows, no known floor."""
    return dataclasses.replace(shipped, depth_pooling="mean", shadow_m=0.0, known_floor=False)


def ms_stats(seconds: Sequence[float], prefix: str = "") -> dict[str, float]:
    """Median and p99 (ms, 3 decimals) of durations in seconds, keys ``{prefix}median_ms`` etc."""
    ms = np.asarray(seconds) * 1e3
    return {
        f"{prefix}median_ms": round(float(np.median(ms)), 3),
        f"{prefix}p99_ms": round(float(np.percentile(ms, 99)), 3),
    }


def write_json(out: dict[str, Any], path: Path | None) -> None:
    if path is not None:
        path.write_text(json.dumps(out, indent=2), encoding="utf-8")
        print(f"wrote {path}")


def decider_with_full_memory(
    policy: Policy, shield: ShieldConfig, scale_m: float
) -> tuple[Decider, DepthFrame, Any, Motion]:
    """A decider at ``scale_m`` whose memory is full: the benchmark frame seen from points 0.25 m
    apart along the path, as in a flight; with that memory and the motion of the next view."""
    prims = PrimitiveSet(scale_m=scale_m, duration_s=scale_m)
    decider = Decider(policy, policy.preprocess_config(), prims, shield)
    frame = DepthFrame(CameraFeed().frame, 0.0, 0)
    memory = decider.memory
    for k in range(decider.shield.memory_steps):
        memory = decider.prepare(frame, decider.snapshot(), _motion(0.25 * k), memory).memory
    return decider, frame, memory, _motion(0.25 * decider.shield.memory_steps)


def time_prepare(policy: Policy, shield: ShieldConfig, scale_m: float, calls: int) -> dict[str, float]:
    decider, frame, memory, motion = decider_with_full_memory(policy, shield, scale_m)
    ts = []
    for _ in range(calls + 20):
        t0 = time.perf_counter()
        decider.prepare(frame, decider.snapshot(), motion, memory)
        ts.append(time.perf_counter() - t0)
    out: dict[str, float] = {"memory_steps": decider.shield.memory_steps, **ms_stats(ts[20:])}
    if shield.enabled:  # the verdict alone (shield_verdict on the full memory), as part of prepare
        m = motion
        mem = decider.prepare(frame, decider.snapshot(), motion, memory).memory
        ts = []
        for _ in range(calls + 20):
            t0 = time.perf_counter()
            shield_verdict(decider.prims, mem.points, mem.depth_m, mem.pose, m.start_world_m[None],
                           m.start_vel_world_m_s[None], np.full(1, m.yaw_rad), m.pos_world_m[None],
                           m.vel_world_m_s[None], decider.shield, floor_z_m=FLOOR_Z_M)
            ts.append(time.perf_counter() - t0)
        out.update(ms_stats(ts[20:], prefix="verdict_"))
    return out


def time_flights(policy: Policy, shield: ShieldConfig, scale_m: float, trials: int,
                 memory_steps: int | None = None, envs: Sequence[int] = range(1, 8)) -> dict[str, float]:
    """Every ``shield_verdict`` call of an evaluation on Env 1-7 (eval seed 0) at ``scale_m``,
    timed; ``memory_steps`` overrides the memory after scaling (None: what the scale implies)."""
    import sim_harness.env as sim_env
    from sim_harness.env import at_primitive_scale
    from sim_harness.rl.evaluate import env_config_for_policy, evaluate, policy_greedy_fn
    from sim_harness.world import load_world, paper_world_path

    worlds = [load_world(paper_world_path(i)) for i in envs]
    cfg, worlds = at_primitive_scale(env_config_for_policy(policy, shield=shield), worlds, scale_m)
    if memory_steps is not None:
        cfg = dataclasses.replace(cfg, shield=dataclasses.replace(cfg.shield, memory_steps=memory_steps))
    ts: list[float] = []
    real = sim_env.shield_verdict

    def timed(*a: Any, **k: Any) -> Any:  # a pass-through
        t0 = time.perf_counter()
        out = real(*a, **k)
        ts.append(time.perf_counter() - t0)
        return out

    sim_env.shield_verdict = timed
    try:
        rows = evaluate(policy_greedy_fn(policy), worlds, trials, 0, cfg)
    finally:
        sim_env.shield_verdict = real
    return {
        "memory_steps": cfg.shield.memory_steps,
        "calls": len(ts),
        "goals": sum(r.outcome == "goal" for r in rows),
        "flights": len(rows),
        **ms_stats(ts, prefix="verdict_"),
    }


def oversleep(policy: Policy, shield: ShieldConfig | None, scale_m: float, sleeps: int = 3000,
              sleep_s: float = 0.002, rate_hz: float = 30.0) -> dict[str, float]:
    """How late ``time.sleep(sleep_s)`` returns on this thread while another thread prepares a frame
    ``rate_hz`` times a second with ``shield`` (None: no other thread)."""
    import threading

    stop = threading.Event()
    worker = None
    prepares = 0
    if shield is not None:
        decider, frame, memory, motion = decider_with_full_memory(policy, shield, scale_m)

        def prepare_at_rate() -> None:
            period = 1.0 / rate_hz
            nxt = time.perf_counter()
            nonlocal prepares
            while not stop.is_set():
                decider.prepare(frame, decider.snapshot(), motion, memory)
                prepares += 1
                nxt += period
                stop.wait(max(0.0, nxt - time.perf_counter()))

        worker = threading.Thread(target=prepare_at_rate, daemon=True)
        worker.start()
    late = np.empty(sleeps)
    try:
        for i in range(sleeps):
            t0 = time.perf_counter()
            time.sleep(sleep_s)
            late[i] = time.perf_counter() - t0 - sleep_s
    finally:
        stop.set()
        if worker is not None:
            worker.join()
    ms = late * 1e3
    return {
        "oversleep_p50_ms": round(float(np.median(ms)), 3),
        "oversleep_p99_ms": round(float(np.percentile(ms, 99)), 3),
        "oversleep_max_ms": round(float(ms.max()), 3),
        "prepares": prepares,
    }


def main_starvation(args: argparse.Namespace, policy: Policy, shipped: ShieldConfig) -> None:
    first = first_filter(shipped)
    out = {"scale_m": args.scale, "sleep_ms": 2.0, "sleeps": 3000, "rate_hz": 30.0, "starvation": {}}
    for name, cfg in (("no preparing thread", None), ("first (mean view, no shadow, no floor)", first),
                      ("shipped", shipped)):
        r = oversleep(policy, cfg, args.scale)
        out["starvation"][name] = r
        print(f"{name:40s} 2-ms sleep overran: p50 {r['oversleep_p50_ms']:.3f} ms  "
              f"p99 {r['oversleep_p99_ms']:.3f} ms  max {r['oversleep_max_ms']:.3f} ms")
    write_json(out, args.json)


def main_flights(args: argparse.Namespace, policy: Policy, shipped: ShieldConfig) -> None:
    out = {"scale_m": args.scale, "trials": args.trials, "flights": {}}
    time_flights(policy, shipped, args.scale, 1, envs=(1,))  # warm-up: compiled kernels, caches
    for name, steps in (("memory of 4 decisions (the first filter)", 4), ("shipped (memory at scale)", None)):
        r = time_flights(policy, shipped, args.scale, args.trials, memory_steps=steps)
        out["flights"][name] = r
        print(f"{name:38s} memory {r['memory_steps']:3d}  verdict median {r['verdict_median_ms']:.3f} ms  "
              f"p99 {r['verdict_p99_ms']:.3f} ms  ({r['calls']} calls, {r['goals']}/{r['flights']} goals)")
    write_json(out, args.json)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", type=float, default=0.25, help="primitive scale flown (bench_daemon: 0.25)")
    ap.add_argument("--calls", type=int, default=300)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--flights", action="store_true", help="time the verdict in eval flights on Env 1-7")
    ap.add_argument("--starvation", action="store_true", help="does preparing frames starve another thread?")
    ap.add_argument("--trials", type=int, default=1,
                    help="--flights: flights per world (1: one vehicle a call)")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(1)
    policy = Policy.from_path(DEFAULT_MODEL_PATH)
    shipped = shield_config_from_meta(policy.checkpoint.meta)
    if args.flights:
        main_flights(args, policy, shipped)
        return
    if args.starvation:
        main_starvation(args, policy, shipped)
        return
    variants = {
        "first (mean view, no shadow, no floor)": first_filter(shipped),
        "shipped": shipped,
        "shipped, shadows kept": dataclasses.replace(shipped, carve_shadows=False),
        "shipped, stop look-ahead": dataclasses.replace(shipped, lookahead="stop"),
        "shield off": dataclasses.replace(shipped, enabled=False),
    }
    out = {"scale_m": args.scale, "calls": args.calls, "prepare": {}}
    for name, cfg in variants.items():
        r = time_prepare(policy, cfg, args.scale, args.calls)
        out["prepare"][name] = r
        verdict = f"  verdict median {r['verdict_median_ms']:.3f} ms" if "verdict_median_ms" in r else ""
        print(f"{name:40s} memory {r['memory_steps']:3d}  prepare median {r['median_ms']:.3f} ms  "
              f"p99 {r['p99_ms']:.3f} ms{verdict}")
    write_json(out, args.json)


if __name__ == "__main__":
    main()
