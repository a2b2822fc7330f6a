"""PX4 over the companion link: the parameters the flight configuration needs, judged by the same
rules preflight applies (quadnav_onboard/daemon/px4_params.py; docs/hardware.md, section 6).

QUADNAV_PX4_URL=serial:///dev/quadnav/fc-usb:921600 (or udpin://0.0.0.0:14540 for SITL), and
QUADNAV_PX4_CONFIG=the flight file to judge against (default config/flight.yaml, the mocap lab's;
config/px4-sitl.yaml for a SITL flown on its own estimate). Read-only: never arms, never sets.
"""

from __future__ import annotations

import asyncio
import os
from pathlib import Path

from conftest import require_env
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.param import ParamAsync

from quadnav_onboard.daemon.config import load_flight_config
from quadnav_onboard.daemon.px4_params import Severity, judge_parameters, parameter_rules

REPO = Path(__file__).resolve().parents[1]

EXTRA = {
    "COM_RCL_EXCEPT": ("int", lambda v: (int(v) & 0b100) == 0, "bit 2 clear: RC loss in Offboard fails safe"),
}
"""Lab checks beyond preflight's (a safety pilot's RC link): printed, not asserted."""


async def _read_params(url: str, names: dict[str, str]) -> dict[str, float | None]:
    config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(url)
        drone = await sdk.first_autopilot(timeout_s=10.0)
        assert drone is not None, f"{url}: no autopilot heartbeat within 10 s"
        param = ParamAsync(drone)
        values: dict[str, float | None] = {}
        for name, kind in names.items():
            getter = param.get_param_float if kind == "float" else param.get_param_int
            try:
                values[name] = float(await asyncio.wait_for(getter(name), 5.0))
            except Exception:  # not answered: a finding of its rule
                values[name] = None
        return values


def test_the_parameters_the_flight_needs_are_set() -> None:
    """No required parameter of the flight configuration is wrong on the connected PX4 (advice is
    printed with -s)."""
    url = require_env("QUADNAV_PX4_URL", "PX4 flight controller or SITL")
    cfg = load_flight_config(os.environ.get("QUADNAV_PX4_CONFIG", str(REPO / "config" / "flight.yaml")))
    rules = parameter_rules(cfg)
    names = {r.name: r.kind for r in rules} | {n: k for n, (k, _, _) in EXTRA.items()}
    values = asyncio.run(_read_params(url, names))
    found = judge_parameters(rules, values)
    print({"values": values, "advice": [str(f) for f in found if f.severity is Severity.ADVICE]})
    for name, (_, ok, want) in EXTRA.items():
        v = values.get(name)
        if v is None or not ok(v):
            print(f"lab check: {name}={v} (want {want})")
    required = [str(f) for f in found if f.severity is Severity.REQUIRED]
    assert not required, f"set these before flying: {required}"
