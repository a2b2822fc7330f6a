"""The daemon against a real PX4 SITL the user started (SIH quadx): preflight with the parameter
check, a straight 20 m mission at 1 m and 0.5 m primitives, SIGINT hold-and-land, offboard loss.

QUADNAV_PX4_SITL=udpin://0.0.0.0:14540 (PX4 SITL's API link) and, optionally,
QUADNAV_PX4_SITL_BRIDGE_PORT=14550 (where PX4 streams the state the sim camera renders from).
Each test runs ``quadnav-onboard --dry-run --px4-sitl`` as a subprocess, as a user would; PX4 must
be disarmed on the ground when a test starts. See sys_test/README.md.
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import yaml
from conftest import require_env

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def sitl_url() -> str:
    return require_env("QUADNAV_PX4_SITL", "PX4 SITL (make px4_sitl sihsim_quadx)")


def _config(tmp_path: Path, url: str, **overrides: Any) -> Path:
    cfg = yaml.safe_load((REPO / "config" / "px4-sitl.yaml").read_text())
    cfg["vehicle"]["url"] = url
    cfg["record"]["enabled"] = False
    for dotted, value in overrides.items():
        section, key = dotted.split(".")
        cfg.setdefault(section, {})
        cfg[section][key] = value
    path = tmp_path / "px4-sitl.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


class Daemon:
    """``quadnav-onboard --dry-run --px4-sitl`` in a subprocess, its JSON log read line by line."""

    def __init__(self, config: Path) -> None:
        port = os.environ.get("QUADNAV_PX4_SITL_BRIDGE_PORT", "14550")
        cmd = [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--px4-sitl", port,
               "--config", str(config), "--json", "--log-format", "json"]
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        self.events: list[dict[str, Any]] = []

    def wait_for(self, pred: Any, timeout_s: float) -> dict[str, Any]:
        assert self.proc.stderr is not None
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            line = self.proc.stderr.readline()
            if not line:
                break
            try:
                ev = json.loads(line)
            except json.JSONDecodeError:
                continue
            self.events.append(ev)
            if pred(ev):
                return ev
        raise AssertionError(f"no such log line within {timeout_s} s; last: {self.events[-5:]}")

    def summary(self, timeout_s: float = 240.0) -> tuple[int, dict[str, Any]]:
        out, _ = self.proc.communicate(timeout=timeout_s)
        return self.proc.returncode, json.loads(out.strip().splitlines()[-1])


def _is_step(n: int) -> Any:
    return lambda ev: ev.get("event") == "step" and ev.get("step", -1) >= n


def test_preflight_reads_the_parameters_and_passes(tmp_path: Path, sitl_url: str) -> None:
    """Preflight reads PX4's parameters over MAVLink (SITL's defaults: advice, no refusal),
    measures the odometry at >= 40 Hz after asking for 50, measures the ground, reaches READY; a
    SIGINT before the go ends it without arming (exit 3)."""
    d = Daemon(_config(tmp_path, sitl_url, **{"trigger.mode": "socket",
                                               "trigger.socket_path": str(tmp_path / "go.sock")}))
    params = d.wait_for(lambda ev: ev.get("check") == "px4_parameters", 120)
    assert params["ok"], params
    rate = d.wait_for(lambda ev: ev.get("event") == "stale_odometry_limit", 60)
    assert rate["measured_hz"] >= 40, rate
    d.wait_for(lambda ev: ev.get("event") == "ready", 60)
    d.proc.send_signal(signal.SIGINT)
    code, s = d.summary()
    assert code == 3 and s["stop_reason"] == "operator_stop" and s["steps"] == 0
    assert s["startup"]["ground"]["source"] == "takeoff"


@pytest.mark.parametrize("scale_m", [1.0, 0.5])
def test_a_straight_20_m_mission_reaches_the_goal_and_lands(
    tmp_path: Path, sitl_url: str, scale_m: float
) -> None:
    """20 m at 2 m above the ground with 1 m (1 m/s) or 0.5 m (0.5 m/s) primitives: goal reached,
    landed, disarmed by PX4 or the daemon, nothing compiled after arming."""
    over = {} if scale_m == 1.0 else {"primitives.scale_m": 0.5, "primitives.duration_s": 1.0,
                                      "mission.speed_m_s": 0.5, "mission.max_steps": 60,
                                      "mission.goal_radius_m": 0.5}
    d = Daemon(_config(tmp_path, sitl_url, **over))
    code, s = d.summary(timeout_s=300)
    assert code == 0 and s["stop_reason"] == "goal_reached", s
    assert s["navigation_distance_m"] > 18.0 and not s["crashed"]
    assert s["landing"]["landed"] and s["landing"]["disarm"] in ("auto", "commanded"), s["landing"]
    assert s["startup"]["kernels_compiled_in_flight"] == {}


def test_sigint_mid_mission_holds_and_lands(tmp_path: Path, sitl_url: str) -> None:
    """SIGINT after 3 steps: operator stop, hold, land, disarmed (exit 3)."""
    d = Daemon(_config(tmp_path, sitl_url))
    d.wait_for(_is_step(3), 180)
    d.proc.send_signal(signal.SIGINT)
    code, s = d.summary()
    assert code == 3 and s["stop_reason"] == "operator_stop", s
    assert s["landing"]["landed"] and s["landing"]["disarm"] in ("auto", "commanded")


async def _watch_px4(url: str, timeout_s: float) -> dict[str, Any]:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

    seen: dict[str, Any] = {"texts": [], "modes": [], "armed": True, "t_disarmed_s": None}
    t0 = time.monotonic()
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as sdk:
        await sdk.add_any_connection(url)
        system = await sdk.first_autopilot(timeout_s=10.0)
        assert system is not None
        tel = TelemetryAsync(system)

        async def texts() -> None:
            async for t in tel.subscribe_status_text():
                seen["texts"].append(t.text)

        async def modes() -> None:
            async for mode in tel.subscribe_flight_mode():
                name = getattr(mode, "name", str(mode))
                if not seen["modes"] or seen["modes"][-1] != name:
                    seen["modes"].append(name)

        tasks = [asyncio.ensure_future(texts()), asyncio.ensure_future(modes())]
        try:
            async for armed in tel.subscribe_armed():
                if not armed:
                    seen["armed"], seen["t_disarmed_s"] = False, time.monotonic() - t0
                    break
                if time.monotonic() - t0 > timeout_s:
                    break
        finally:
            for t in tasks:
                t.cancel()
    return seen


def test_offboard_loss_failsafe_lands_and_disarms(tmp_path: Path, sitl_url: str) -> None:
    """The daemon killed (SIGKILL) after 3 steps: PX4 announces the failsafe, lands and disarms
    within 30 s by itself."""
    d = Daemon(_config(tmp_path, sitl_url))
    d.wait_for(_is_step(3), 180)
    d.proc.kill()
    d.proc.wait(10)
    time.sleep(1.0)  # the daemon's port is free again; its vehicle-side children have exited
    seen = asyncio.run(_watch_px4(sitl_url, 40.0))
    assert not seen["armed"] and seen["t_disarmed_s"] < 30.0, seen
    assert any("Failsafe" in t for t in seen["texts"]), seen["texts"]
    assert "LAND" in seen["modes"], seen["modes"]
