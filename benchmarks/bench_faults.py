"""The daemon's reaction to every fault the emulated PX4 injects (sim_harness/px4/faults.py), and to
the vehicle's process dying or a second vehicle appearing: stop reason, exit code, the time from
the fault to the stop decision and to the daemon's exit, and the commands sent after the fault.

Each run flies the real daemon, real MAVSDK and real UDP against the emulator
(``sim_harness.px4.link_rig``: a 3 m path, 0.5 s steps, 10 Hz heartbeat, default safety limits:
``link_timeout_s`` 0.5 s, ``stale_odometry_s`` 0.1 s); the fault is injected once the mission
made its first step. Prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_faults.py --runs 3 --out bench_faults.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import platform
import statistics
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import structlog

from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.policy import Policy
from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port
from sim_harness.px4.link_rig import LinkFlight, modes_entered

FAST = EmulatorConfig(heartbeat_hz=10.0)


@dataclass(frozen=True)
class Scenario:
    name: str
    """Row name: the fault (faults.py's kind where it is one)."""
    what: str
    """What is injected."""
    fault: Callable[[LinkFlight, dict[str, Any]], None] | None = None
    """Called once the mission made its first step (None: nothing mid-flight)."""
    before: Callable[[Px4Emulator, dict[str, Any]], None] | None = None
    """Called before the daemon starts."""
    px4_odometry: bool = False
    """The daemon's odometry is PX4's ODOMETRY (else the emulator's true pose, a mocap)."""


def _kill(f: LinkFlight, extra: dict[str, Any], mocap_too: bool) -> None:
    f.emu.stop()
    if mocap_too:
        f.odometry.paused = True


def _second_vehicle(port: int) -> Callable[[Any, dict[str, Any]], None]:
    def start(_: Any, extra: dict[str, Any]) -> None:
        extra.setdefault("others", []).append(Px4Emulator(None, FAST, api_port=port).start())

    return start


def scenarios(port: int) -> list[Scenario]:
    return [
        Scenario("drop_link", "drop_link for 2.5 s", lambda f, _: f.emu.faults.drop_link(0.0, 2.5)),
        Scenario("delay_link", "delay_link 0.3 s each way for 3 s",
                 lambda f, _: f.emu.faults.delay_link(0.0, 3.0, 0.3)),
        Scenario("freeze_position", "freeze_position for 1 s (mocap odometry)",
                 lambda f, _: f.emu.faults.freeze_position(0.0, 1.0)),
        Scenario("freeze_position (px4 odometry)", "freeze_position for 1 s (PX4's ODOMETRY)",
                 lambda f, _: f.emu.faults.freeze_position(0.0, 1.0), px4_odometry=True),
        Scenario("deny_mode OFFBOARD", "deny_mode OFFBOARD before the flight",
                 before=lambda emu, _: emu.faults.deny_mode("OFFBOARD")),
        Scenario("deny_mode HOLD", "deny_mode HOLD mid-flight (the ladder's first rung)",
                 lambda f, _: f.emu.faults.deny_mode("HOLD")),
        Scenario("crash", "crash_now (no crash probe, as on a real vehicle)",
                 lambda f, _: f.emu.faults.crash_now()),
        Scenario("vehicle killed", "the emulator stopped (its process dies)",
                 lambda f, x: _kill(f, x, mocap_too=False)),
        Scenario("vehicle killed, mocap too", "the emulator stopped, odometry stops with it",
                 lambda f, x: _kill(f, x, mocap_too=True)),
        Scenario("second vehicle in flight", "a second emulator, same system ID, on the daemon's port",
                 _second_vehicle(port)),
        Scenario("second vehicle at start", "two emulators, same system ID, before the daemon starts",
                 before=_second_vehicle(port)),
    ]


async def one_run(policy: Policy, pick: str) -> dict[str, Any]:
    port = free_udp_port()
    sc = next(s for s in scenarios(port) if s.name == pick)
    extra: dict[str, Any] = {}
    with Px4Emulator(None, FAST, api_port=port) as emu:
        try:
            if sc.before is not None:
                sc.before(emu, extra)
            flight = LinkFlight(policy, emu, port, px4_odometry=sc.px4_odometry)
            s = await flight.run((lambda f: sc.fault(f, extra)) if sc.fault is not None else None)
            t0 = flight.t_fault
            if sc.name == "deny_mode OFFBOARD":  # from the refused switch
                t0 = next((t for t, name in flight.vehicle.calls if name == "offboard_start"), None)
            elif t0 is None:  # present from the start: from the daemon's start
                t0 = flight.t_start
            stop_ms = None if t0 is None or flight.t_stop is None else (flight.t_stop - t0) * 1e3
            exit_ms = None if t0 is None or flight.t_end is None else (flight.t_end - t0) * 1e3
            return {
                "stop_reason": s.stop_reason,
                "exit_code": s.exit_code,
                "crashed": s.crashed,
                "fault_to_stop_ms": stop_ms,
                "fault_to_exit_ms": exit_ms,
                "commands_after_fault": flight.vehicle.commands_after(t0) if t0 is not None else [],
                "modes_after": modes_entered(emu)[-3:],
                "detail": s.detail,
            }
        finally:
            for other in extra.get("others", []):
                other.stop()


def _stat(values: list[float | None]) -> dict[str, float | None]:
    xs = [v for v in values if v is not None]
    if not xs:
        return {"median": None, "max": None}
    return {"median": round(statistics.median(xs), 1), "max": round(max(xs), 1)}


async def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=3, help="runs per fault (default 3)")
    parser.add_argument("--only", action="append", default=None, help="run only this fault (repeatable)")
    parser.add_argument("--out", type=Path, default=Path("bench_faults.json"), help="JSON output file")
    args = parser.parse_args()
    structlog.configure(wrapper_class=structlog.make_filtering_bound_logger(40))  # errors only
    with tempfile.TemporaryDirectory() as tmp:
        policy = Policy(constant_action_checkpoint(str(Path(tmp) / "fwd.pt"), 4))
        names = args.only or [s.name for s in scenarios(0)]
        results: dict[str, Any] = {
            "machine": platform.platform(), "python": platform.python_version(), "runs": args.runs,
            "faults": {},
        }
        for name in names:
            runs = [await one_run(policy, name) for _ in range(args.runs)]
            results["faults"][name] = {
                "what": next(s.what for s in scenarios(0) if s.name == name),
                "stop_reasons": sorted({r["stop_reason"] for r in runs}),
                "exit_codes": sorted({r["exit_code"] for r in runs}),
                "fault_to_stop_ms": _stat([r["fault_to_stop_ms"] for r in runs]),
                "fault_to_exit_ms": _stat([r["fault_to_exit_ms"] for r in runs]),
                "runs": runs,
            }
            row = results["faults"][name]
            print(
                f"{name:32s} {','.join(row['stop_reasons']):28s} exit {row['exit_codes']}  "
                f"stop {row['fault_to_stop_ms']['median']} ms (max {row['fault_to_stop_ms']['max']})  "
                f"exit {row['fault_to_exit_ms']['median']} ms  "
                f"commands after: {sorted({c for r in runs for c in r['commands_after_fault']})}",
                flush=True,
            )
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    asyncio.run(main())
