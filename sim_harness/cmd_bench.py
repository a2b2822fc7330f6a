"""``quadnav-sim bench``: rendering figures (and env-step figures when ``sim_harness.bench_env`` exists).

Figures, not tests: they are printed with the machine's core count and load, and as JSON with
``--json`` (stdout) or ``--out PATH``. Targets: 32x32 rendering on the densest paper world
>= 10,000 frames/s batched; one 848x480 frame <= 20 ms.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["add_parser", "run_render"]

TARGET_FPS_32 = 10_000.0
TARGET_FRAME_MS_848 = 20.0


def _densest_world():  # -> World
    from sim_harness.world import load_world, paper_world_path

    worlds = [load_world(paper_world_path(i)) for i in range(1, 11)]
    return max(worlds, key=lambda w: len(w.obstacles))


def _poses(world, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Poses a quad can be in: along the path, off it by up to 1.5 m, heading +-0.5 rad."""
    from sim_harness.collision import clearance_m

    pos = np.stack([rng.uniform(0, 60, 3 * n), rng.uniform(-1.5, 1.5, 3 * n), rng.uniform(1, 3, 3 * n)], -1)
    pos = pos[clearance_m(world, pos) > 0.3][:n]
    return pos, rng.uniform(-0.5, 0.5, len(pos))


def _rate(fn, n_items: int, seconds: float) -> dict[str, float]:
    """Items/s of ``fn`` over repeated calls for about ``seconds`` (median and best call)."""
    rates: list[float] = []
    t_end = time.perf_counter() + seconds
    while time.perf_counter() < t_end or len(rates) < 3:
        t0 = time.perf_counter()
        fn()
        rates.append(n_items / (time.perf_counter() - t0))
    return {"median": round(statistics.median(rates), 1), "best": round(max(rates), 1), "calls": len(rates)}


def _frame_ms(fn, n: int) -> dict[str, float]:
    ms = []
    for k in range(n):
        t0 = time.perf_counter()
        fn(k)
        ms.append(1e3 * (time.perf_counter() - t0))
    return {"median": round(statistics.median(ms), 3), "p90": round(float(np.percentile(ms, 90)), 3),
            "best": round(min(ms), 3)}


def run_render(seconds: float = 2.0, batch: int = 4096, seed: int = 0,
               threads: int | None = None) -> dict[str, Any]:
    """Measure the renderer; returns a JSON-ready dict (see module docstring for the targets)."""
    import numba

    from quadnav_onboard.frames import quat_from_yaw
    from sim_harness import render
    from sim_harness.noise import DepthNoise

    if threads:
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))
    world = _densest_world()
    rng = np.random.default_rng(seed)
    pos, yaw = _poses(world, batch, rng)
    t0 = time.perf_counter()
    render.render_network_inputs(world, pos[:2], yaw[:2])  # first call: JIT compile or cache load
    render.render_frame_mm(world, pos[0], quat_from_yaw(yaw[0]), render.D435_848x480)
    first_call_s = time.perf_counter() - t0
    quats = quat_from_yaw(yaw)
    noise, noise_rng = DepthNoise(), np.random.default_rng(seed)
    fps = {f"supersample_{s}": _rate(lambda s=s: render.render_network_inputs(world, pos, yaw, supersample=s),
                                     len(pos), seconds) for s in (2, 1)}
    cams = {"848x480": render.D435_848x480, "424x240": render.D435_424x240}
    frames = {
        name: _frame_ms(lambda k, c=cam: render.render_frame_mm(world, pos[k], quats[k], c), 60)
        for name, cam in cams.items()
    } | {
        "848x480_noisy": _frame_ms(lambda k: render.render_frame_mm(
            world, pos[k], quats[k], render.D435_848x480, noise, noise_rng), 30),
    }
    fps32 = fps["supersample_2"]["median"]
    return {
        "benchmark": "render",
        "world": world.name,
        "n_obstacles": len(world.obstacles),
        "batch_poses": len(pos),
        "network_inputs_32x32_frames_per_s": fps,
        "full_frame_ms": frames,
        "uses": (f"numba {numba.__version__} njit(parallel, cache=True): analytic ray casting, oriented-box "
                 "screen-rectangle culling, nearest-first occlusion skip; training path casts 2x2 rays per "
                 "32x32 pixel (supersample_2, the default)"),
        "numba_threads": numba.get_num_threads(),
        "numba_threading_layer": numba.threading_layer(),
        "first_call_s": round(first_call_s, 3),
        "cpu_count": os.cpu_count(),
        "load_avg_1min": round(os.getloadavg()[0], 2),
        "target_frames_per_s_32": TARGET_FPS_32,
        "target_frame_ms_848": TARGET_FRAME_MS_848,
        "meets_target_32": fps32 >= TARGET_FPS_32,
        "meets_target_848": frames["848x480"]["median"] <= TARGET_FRAME_MS_848,
    }


def _print_render(r: dict[str, Any]) -> None:
    print(f"render  world {r['world']} ({r['n_obstacles']} obstacles), {r['cpu_count']} cores, "
          f"{r['numba_threads']} numba threads ({r['numba_threading_layer']}), load {r['load_avg_1min']}")
    for name, v in r["network_inputs_32x32_frames_per_s"].items():
        print(f"  32x32 {name:<14} {v['median']:>10,.0f} frames/s (best {v['best']:,.0f}; "
              f"target {r['target_frames_per_s_32']:,.0f})")
    for name, v in r["full_frame_ms"].items():
        print(f"  frame {name:<14} {v['median']:>10.2f} ms median, p90 {v['p90']:.2f} ms")
    print(f"  first call (JIT compile or cache load) {r['first_call_s']:.2f} s; meets targets: "
          f"32x32 {r['meets_target_32']}, 848x480 {r['meets_target_848']}")


def _run(args: argparse.Namespace) -> int:
    results: dict[str, Any] = {"render": run_render(args.seconds, args.batch, args.seed, args.threads)}
    if not args.json:
        _print_render(results["render"])
    try:
        bench_env = importlib.import_module("sim_harness.bench_env")
    except ModuleNotFoundError as exc:
        if exc.name != "sim_harness.bench_env":
            raise
        bench_env = None
    if bench_env is not None and not args.render_only:
        results["env"] = bench_env.run(seconds=args.seconds, seed=args.seed, sim_threads=args.threads)
        if not args.json:
            env = results["env"]
            print(f"env     best {env.get('best_env_steps_per_s')} steps/s "
                  f"(target {env.get('target_env_steps_per_s')})")
            for row in env.get("results", []):
                print(f"  {row}")
    if args.json:
        json.dump(results, sys.stdout, indent=2)
        print()
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=2) + "\n")
    return 0


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser("bench", help="measure rendering and env-step speed",
                              description="Measure rendering (and env-step) speed; print the figures "
                              "with the core count, or as JSON.")
    p.add_argument("--json", action="store_true", help="print the figures as JSON instead of text")
    p.add_argument("--out", metavar="PATH", help="also write the JSON figures to PATH")
    p.add_argument("--seconds", type=float, default=2.0, help="time per measurement (s)")
    p.add_argument("--batch", type=int, default=4096, help="poses per 32x32 render call")
    p.add_argument("--seed", type=int, default=0, help="seed of the sampled poses")
    p.add_argument("--threads", type=int, default=None, help="numba threads (default: all cores)")
    p.add_argument("--render-only", action="store_true", help="skip the env-step benchmark")
    p.set_defaults(func=_run)
