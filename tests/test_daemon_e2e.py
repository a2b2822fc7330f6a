"""End to end: the real daemon, real MAVSDK and real UDP against the emulated PX4 (no mocks between).

Short worlds (a 3 m path), 0.5 s steps of 0.5 m primitives, a 10 Hz emulator heartbeat, and a
constant "straight ahead" model (the trained one is not the subject here).
"""

from __future__ import annotations

import asyncio
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import AsyncIterator, Callable
from pathlib import Path
from typing import Any

import pytest

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, MissionConfig, SafetyConfig
from quadnav_onboard.daemon.dryrun import DryRun
from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.policy import Policy
from quadnav_onboard.sources.base import DepthFrame

pytestmark = [pytest.mark.e2e, pytest.mark.slow]

LEFT_FORWARD = 7


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory, straight_world: Callable[[Path, float], Path]) -> Path:
    return straight_world(tmp_path_factory.mktemp("w"), 3.0)


@pytest.fixture(scope="module")
def model(forward_model: Path) -> Path:
    return forward_model


def config(**safety: Any) -> FlightConfig:
    prims = parse_config(PrimitiveConfig, {"scale_m": 0.5, "duration_s": 0.5})
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=30),
        primitives=prims,
        safety=SafetyConfig(**{"hold_before_land_s": 0.3, "land_timeout_s": 15.0, **safety}),
    )


class PausableDepth:
    """A real depth source whose feed can be cut (the camera cable pulled)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.cut = False

    async def __aenter__(self) -> PausableDepth:
        await self.inner.__aenter__()
        return self

    async def __aexit__(self, *exc: object) -> None:
        await self.inner.__aexit__(*exc)

    async def frames(self) -> AsyncIterator[DepthFrame]:
        async for f in self.inner.frames():
            if not self.cut:
                yield f


async def fly(
    world: Path,
    model: Path,
    cfg: FlightConfig,
    fault: Callable[[DryRun, dict[str, Any]], None] | None = None,
    lands: bool = True,
) -> tuple[Any, DryRun, dict[str, Any]]:
    with DryRun(cfg, world, emulator={"heartbeat_hz": 10.0}) as sim:
        parts = sim.parts()
        parts["depth"] = PausableDepth(parts["depth"])
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(model), **parts)

        async def inject() -> None:
            while not (daemon.in_mission and daemon.steps >= 1):
                await asyncio.sleep(0.02)
            fault(sim, parts)  # type: ignore[misc]

        task = asyncio.ensure_future(inject()) if fault else None
        summary = await asyncio.wait_for(daemon.run(), 60)
        if task:
            task.cancel()
        if lands:
            sim.emulator.wait_for(lambda e: not e.armed, 15.0)
        sim.events = list(sim.emulator.events)  # type: ignore[attr-defined]
        sim.final_armed = sim.emulator.armed  # type: ignore[attr-defined]
        sim.final_mode = sim.emulator.mode  # type: ignore[attr-defined]
        return summary, sim, parts


def modes_entered(sim: Any) -> list[str]:
    """Modes the emulated PX4 entered, in order (from its event log: "A -> B")."""
    return [msg.split(" -> ")[1] for _, kind, msg in sim.events if kind == "mode"]


async def test_a_full_flight_reaches_the_goal_and_lands(world: Path, model: Path) -> None:
    s, sim, _ = await fly(world, model, config())
    assert s.stop_reason == "goal_reached" and s.exit_code == 0, s
    assert not s.crashed and s.navigation_distance_m > 2.0 and s.total_reward > 0
    assert modes_entered(sim)[-3:] == ["OFFBOARD", "HOLD", "LAND"] and not sim.final_armed


async def test_depth_feed_stopping_holds_then_lands(world: Path, model: Path) -> None:
    s, sim, _ = await fly(world, model, config(), lambda sim, parts: setattr(parts["depth"], "cut", True))
    assert s.stop_reason == "stale_depth" and s.exit_code == 3
    assert s.hold_reaction_ms is not None and s.hold_reaction_ms < 100
    assert modes_entered(sim)[-2:] == ["HOLD", "LAND"] and not sim.final_armed


async def test_mocap_dropout_holds(world: Path, model: Path) -> None:
    s, sim, _ = await fly(
        world, model, config(land_on_abort=False), lambda sim, parts: parts["odometry"].pause(), lands=False
    )
    assert s.stop_reason == "stale_odometry"
    assert modes_entered(sim)[-1] == "HOLD" and sim.final_armed  # holding in the air, as configured


async def test_link_drop_triggers_px4_failsafe_and_the_daemon_does_not_fight_on_reconnect(
    world: Path, model: Path
) -> None:
    def drop(sim: DryRun, parts: dict[str, Any]) -> None:
        sim.emulator.faults.drop_link(0.0, 2.5)

    t0 = time.monotonic()
    with DryRun(config(), world, emulator={"heartbeat_hz": 10.0, "offboard_loss_action": "hold"}) as sim:
        parts = sim.parts()
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(model), **parts)

        async def inject() -> None:
            while not (daemon.in_mission and daemon.steps >= 1):
                await asyncio.sleep(0.02)
            drop(sim, parts)

        task = asyncio.ensure_future(inject())
        s = await asyncio.wait_for(daemon.run(), 60)
        await task
        assert s.stop_reason == "link_lost" and s.exit_code == 3
        assert sim.emulator.wait_for(lambda e: e.mode == "HOLD", 3.0)  # PX4's offboard-loss failsafe
        time.sleep(max(0.0, 3.5 - (time.monotonic() - t0)))  # link back
        time.sleep(1.0)
        assert sim.emulator.mode == "HOLD" and sim.emulator.armed  # nobody switched back to OFFBOARD


async def test_step_limit_holds(world: Path, model: Path) -> None:
    cfg = config()
    cfg = FlightConfig(**{**cfg.__dict__, "mission": MissionConfig(takeoff_speed_m_s=2.0, max_steps=2)})
    s, sim, _ = await fly(world, model, cfg)
    assert s.stop_reason == "step_limit" and s.steps == 2
    assert modes_entered(sim)[-2:] == ["HOLD", "LAND"]


async def test_deviation_limit_holds(world: Path, tmp_path: Path) -> None:
    left = tmp_path / "left.pt"
    constant_action_checkpoint(str(left), LEFT_FORWARD)
    s, sim, _ = await fly(world, left, config(max_deviation_m=0.4))
    assert s.stop_reason == "deviation" and s.exit_code == 3
    assert modes_entered(sim)[-2:] == ["HOLD", "LAND"] and not sim.final_armed


def test_sigterm_mid_flight_lands_flushes_the_record_and_exits_safe_abort(
    world: Path, model: Path, tmp_path: Path
) -> None:
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(
        "mission: {max_steps: 30, takeoff_speed_m_s: 2.0}\n"
        "primitives: {scale_m: 0.5, duration_s: 0.5}\n"
        "safety: {hold_before_land_s: 0.3}\n"
        "depth: {kind: sim}\nodometry: {kind: sim}\ntrigger: {mode: auto}\n"
    )
    rec = tmp_path / "rec"
    cmd = [
        sys.executable,
        "-m",
        "quadnav_onboard.cli",
        "--dry-run",
        "--config",
        str(cfg),
        "--world",
        str(world),
        "--model",
        str(model),
        "--json",
        "--record-dir",
        str(rec),
        "--log-format",
        "json",
    ]
    proc = subprocess.Popen(
        cmd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
    )
    assert proc.stderr is not None
    deadline = time.monotonic() + 60
    for line in proc.stderr:
        if '"event": "step"' in line:
            break
        assert time.monotonic() < deadline
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 3, err[-2000:]
    summary = json.loads(out)
    assert summary["stop_reason"] == "operator_stop"
    assert '"landed"' in err
    from quadnav_onboard.record.reader import read_record

    (record,) = rec.glob("*.mcap")
    r = read_record(record, load_depth=False)
    assert r is not None and record.stat().st_size > 0
