"""PX4 over the companion link: heartbeat, and the parameters docs/hardware.md requires.

QUADNAV_PX4_URL=serial:///dev/quadnav/fc-usb:921600 (or udpin://0.0.0.0:14540 for SITL).
Read-only: this test never arms, never changes a parameter.
"""

from __future__ import annotations

import asyncio

from conftest import require_env
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.param import ParamAsync

# name -> (kind, check, what docs/hardware.md says)
REQUIRED = {
    "COM_OF_LOSS_T": ("float", lambda v: 0.2 <= v <= 1.0, "offboard loss timeout 0.5 s (<= 1 s)"),
    "COM_OBL_RC_ACT": ("int", lambda v: v in (0, 4, 5), "offboard loss: Position (0), Land (4), Hold (5)"),
    "COM_RCL_EXCEPT": ("int", lambda v: (v & 0b100) == 0, "no RC-loss exception for Offboard (bit 2)"),
    "EKF2_EV_CTRL": ("int", lambda v: (v & 0b1011) == 0b1011, "vision: horizontal + vertical pos, yaw"),
    "EKF2_HGT_REF": ("int", lambda v: v == 3, "height reference: vision (3)"),
    "COM_RC_IN_MODE": ("int", lambda v: v in (0, 2, 3), "RC required for a safety pilot"),
}


async def _read_params(url: str) -> dict[str, float]:
    config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
    async with Mavsdk(config) as sdk:
        await sdk.add_any_connection(url)
        drone = await sdk.first_autopilot(timeout_s=10.0)
        assert drone is not None, f"{url}: no autopilot heartbeat within 10 s"
        param = ParamAsync(drone)
        values = {}
        for name, (kind, _, _) in REQUIRED.items():
            getter = param.get_param_float if kind == "float" else param.get_param_int
            values[name] = await asyncio.wait_for(getter(name), 5.0)
        return values


def test_failsafe_and_vision_parameters_are_set() -> None:
    """Every parameter in docs/hardware.md's table has a safe value on the connected PX4."""
    url = require_env("QUADNAV_PX4_URL", "PX4 flight controller")
    values = asyncio.run(_read_params(url))
    wrong = {n: (values[n], REQUIRED[n][2]) for n in REQUIRED if not REQUIRED[n][1](values[n])}
    print(values)
    assert not wrong, f"set these before flying: {wrong}"
