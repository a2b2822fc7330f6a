"""Connect-to-offboard time against the emulated PX4, with a 1 Hz and a 10 Hz heartbeat.

Measures, per run, with the real MAVSDK over loopback UDP: MAVSDK connection added -> autopilot
discovered -> local-position health -> armed -> OFFBOARD accepted. Prints a table and writes JSON.

    .venv/bin/python benchmarks/bench_connect.py --runs 5 --out bench_connect.json
"""

from __future__ import annotations

import argparse
import asyncio
import json
import platform
import statistics
import time
from pathlib import Path

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from sim_harness.px4 import EmulatorConfig, Px4Emulator, free_udp_port


async def one_run(heartbeat_hz: float) -> dict[str, float]:
    with Px4Emulator(None, EmulatorConfig(heartbeat_hz=heartbeat_hz), api_port=free_udp_port()) as emu:
        marks: dict[str, float] = {}
        config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        async with Mavsdk(config) as sdk:
            t0 = time.monotonic()
            await sdk.add_any_connection(f"udpin://127.0.0.1:{emu.api_port}")
            drone = await sdk.first_autopilot(timeout_s=10.0)
            assert drone is not None
            marks["discovered_s"] = time.monotonic() - t0
            tel = TelemetryAsync(drone)
            async with asyncio.timeout(10.0):
                async for health in tel.subscribe_health():
                    if health.is_local_position_ok:
                        break
            marks["healthy_s"] = time.monotonic() - t0
            await ActionAsync(drone).arm()
            marks["armed_s"] = time.monotonic() - t0
            offboard = OffboardAsync(drone)
            await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -1.0, 0.0))
            await offboard.start()
            marks["offboard_s"] = time.monotonic() - t0
            assert emu.mode == "OFFBOARD"
    return marks


async def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--runs", type=int, default=5, help="runs per heartbeat rate (default 5)")
    parser.add_argument("--out", type=Path, default=Path("bench_connect.json"), help="JSON output file")
    args = parser.parse_args()
    results: dict[str, object] = {"machine": platform.platform(), "python": platform.python_version(),
                                  "runs": args.runs, "rates": {}}
    print(f"{'heartbeat':>9} {'discovered':>11} {'healthy':>9} {'armed':>9} {'offboard':>9}  (median s)")
    for hz in (1.0, 10.0):
        runs = [await one_run(hz) for _ in range(args.runs)]
        median = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
        results["rates"][f"{hz:g}Hz"] = {"median": median, "runs": runs}  # type: ignore[index]
        print(f"{hz:>7g}Hz {median['discovered_s']:>11.3f} {median['healthy_s']:>9.3f} "
              f"{median['armed_s']:>9.3f} {median['offboard_s']:>9.3f}")
    args.out.write_text(json.dumps(results, indent=2))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    asyncio.run(main())
