"""The daemon's lifecycle and supervisor responses, against in-memory fakes (quadnav_onboard.daemon.testing).

Fast flights: 0.25 s steps of 0.25 m primitives along a 1.5 m path. End-to-end behaviour over real
MAVLink is in test_daemon_e2e.py.
"""

from __future__ import annotations

import asyncio
import dataclasses
import signal
import time
from pathlib import Path

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, MissionConfig, OdometrySourceConfig, SafetyConfig
from quadnav_onboard.daemon.testing import (
    FakeDepthSource,
    FakeOdometrySource,
    FakeVehicle,
    constant_action_checkpoint,
)
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy
from quadnav_onboard.vehicle import VehicleError, VehicleErrorKind

PATH = RoughPath(np.array([[0.0, 0.0, 1.0], [1.5, 0.0, 1.0]]), 1.0)
FORWARD, LEFT_FORWARD = 4, 7


def fast_config(**mission: object) -> FlightConfig:
    prims = parse_config(PrimitiveConfig, {"scale_m": 0.25, "duration_s": 0.25})
    return FlightConfig(
        mission=MissionConfig(**{"takeoff_speed_m_s": 3.0, "max_steps": 40, "goal_radius_m": 0.2, **mission}),
        primitives=prims,
        # Fakes run in this process: staleness limits leave room for a loaded CI box (timing figures
        # live in benchmarks/bench_daemon.py).
        safety=SafetyConfig(hold_before_land_s=0.05, land_timeout_s=5.0, stale_odometry_s=0.3),
    )


@pytest.fixture(scope="module")
def forward_policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    return Policy(constant_action_checkpoint(str(tmp_path_factory.mktemp("m") / "fwd.pt"), FORWARD))


class Rig:
    def __init__(
        self,
        policy: Policy,
        cfg: FlightConfig | None = None,
        path: RoughPath = PATH,
        vehicle: FakeVehicle | None = None,
        **kw: object,
    ) -> None:
        self.vehicle = vehicle or FakeVehicle()
        self.depth = FakeDepthSource(fps=30.0)
        self.odom = FakeOdometrySource(lambda: self.vehicle.pos_world_m, rate_hz=100.0)
        self.daemon = FlightDaemon(
            cfg or fast_config(),
            path=path,
            policy=policy,
            depth=self.depth,
            odometry=self.odom,
            vehicle=self.vehicle,
            **kw,
        )

    def commands(self) -> list[str]:
        return [c for _, c in self.vehicle.commands if c != "vision"]

    async def when(self, cond, timeout_s: float = 5.0) -> None:
        async with asyncio.timeout(timeout_s):
            while not cond():
                await asyncio.sleep(0.01)

    async def in_mission_then(self, action, min_steps: int = 1):
        async def go() -> None:
            await self.when(
                lambda: (
                    self.daemon.in_mission
                    and self.daemon.pending_step is not None
                    and self.daemon.pending_step.step >= min_steps - 1
                )
            )
            action()

        trigger = asyncio.ensure_future(go())
        summary = await asyncio.wait_for(self.daemon.run(), 15)
        await trigger
        return summary


async def test_a_clear_path_is_flown_to_the_goal_then_held_and_landed(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "goal_reached" and s.exit_code == 0
    assert rig.commands() == ["arm", "offboard_start", "hold", "land"]
    assert s.navigation_distance_m > 1.2 and s.steps >= 5 and s.total_reward > 0
    assert not rig.vehicle.state.armed  # landed and disarmed
    assert s.decision_latency_ms["n"] == s.steps


async def test_decisions_use_frames_prepared_on_arrival(forward_policy: Policy) -> None:
    """Frames are prepared as they arrive, so steps run only the head; every step is counted once."""
    rig = Rig(forward_policy)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "goal_reached"
    assert sum(s.decision_paths.values()) == s.steps
    assert s.decision_paths["prepared"] >= 1
    assert s.frame_age_ms["n"] == s.steps and s.frame_age_ms["max_ms"] < 300


async def test_depth_feed_stopping_mid_flight_holds_then_lands(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: setattr(rig.depth, "paused", True), min_steps=2)
    assert s.stop_reason == "stale_depth" and s.exit_code == 3
    assert rig.commands()[-2:] == ["hold", "land"]
    assert s.hold_reaction_ms is not None  # the <= 100 ms figure is measured in benchmarks/


async def test_mocap_dropout_holds(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: setattr(rig.odom, "paused", True))
    assert s.stop_reason == "stale_odometry"
    assert "hold" in rig.commands()


async def test_nan_odometry_in_flight_stops(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: setattr(rig.odom, "nan", True))
    assert s.stop_reason == "bad_odometry" and "hold" in rig.commands()


async def test_wrong_dtype_depth_in_flight_stops(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(
        lambda: setattr(rig.depth, "make", lambda i: np.ones((240, 424), np.float32))
    )
    assert s.stop_reason == "bad_depth" and "hold" in rig.commands()


async def test_a_blank_depth_frame_in_flight_stops_for_bad_depth(forward_policy: Policy) -> None:
    """All-invalid frames (camera blocked) pass the cheap dtype check but not preprocessing: bad_depth."""
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: setattr(rig.depth, "depth_mm", 0))
    assert s.stop_reason == "bad_depth" and s.exit_code == 3 and "valid pixels" in s.detail
    assert "hold" in rig.commands()


def slow_step_config(prepare_within_s: float | None) -> FlightConfig:
    """1-s steps (a real flight's), so most frames arrive well before the next step boundary."""
    cfg = fast_config(max_steps=3)
    prims = parse_config(PrimitiveConfig, {"scale_m": 0.25, "duration_s": 1.0})
    depth = dataclasses.replace(cfg.depth, prepare_within_s=prepare_within_s)
    return dataclasses.replace(cfg, primitives=prims, depth=depth)


SLOW_PATH = RoughPath(PATH.waypoints_m, 0.25)  # the moving setpoint: one 0.25-m primitive per 1-s step


@pytest.mark.parametrize("window_s", [0.1, None])
async def test_only_frames_near_a_step_boundary_are_prepared(forward_policy: Policy, window_s) -> None:
    """``depth.prepare_within_s``: in the mission, frames that arrive earlier than that before the
    next step are only checked; every decision still finds its frame (prepared or prepared in the
    step). null: every frame is prepared, none only checked."""
    rig = Rig(forward_policy, slow_step_config(window_s), path=SLOW_PATH)
    before: dict[str, int] = {}  # the take-off's frames (all prepared: no step boundary is due)

    def at_mission_start() -> None:
        before["prepared"] = rig.daemon.stats.depth_frames_prepared

    s = await rig.in_mission_then(at_mission_start)
    assert s.stop_reason == "step_limit" and sum(s.decision_paths.values()) == s.steps == 3
    frames = s.depth_frames
    assert frames["prepared"] + frames["checked"] <= frames["received"] + s.steps
    if window_s is None:
        assert frames["checked"] == 0 and frames["prepared"] >= s.steps
    else:  # 1-s steps at 30 fps: about 3 of every 30 frames in the mission are prepared
        in_mission = frames["prepared"] - before["prepared"]
        assert frames["checked"] > 2 * in_mission > 0, (frames, before)


async def test_a_bad_frame_early_in_a_step_stops_the_flight_before_the_next_step(
    forward_policy: Policy,
) -> None:
    """A frame only checked (too early to be prepared) still stops the flight on arrival, not at
    the next step boundary."""
    rig = Rig(forward_policy, slow_step_config(0.1), path=SLOW_PATH)
    timing: dict[str, float] = {}

    async def blank_frames_after_step_1() -> None:
        await rig.when(lambda: rig.daemon.pending_step is not None and rig.daemon.pending_step.step >= 1)
        timing["to_boundary_s"] = rig.daemon.next_step_mono - time.monotonic()  # type: ignore[operator]
        t_bad = time.monotonic()
        rig.depth.depth_mm = 0
        await rig.when(lambda: rig.daemon.stop_reason is not None)
        timing["to_stop_s"] = time.monotonic() - t_bad

    trigger = asyncio.ensure_future(blank_frames_after_step_1())
    s = await asyncio.wait_for(rig.daemon.run(), 20)
    await trigger
    assert s.stop_reason == "bad_depth" and "valid pixels" in s.detail
    assert timing["to_boundary_s"] > 0.5  # the blank frames began early in the step
    assert timing["to_stop_s"] < timing["to_boundary_s"] - 0.2  # caught on arrival, not at the step
    assert s.depth_frames["checked"] >= 1


async def test_the_step_limit_holds(forward_policy: Policy) -> None:
    rig = Rig(forward_policy, fast_config(max_steps=2))
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "step_limit" and s.steps == 2 and rig.commands()[2] == "hold"


async def test_leaving_the_path_past_the_deviation_limit_holds(tmp_path: Path) -> None:
    policy = Policy(constant_action_checkpoint(str(tmp_path / "left.pt"), LEFT_FORWARD))
    cfg = fast_config()
    cfg = FlightConfig(
        **{**cfg.__dict__, "safety": SafetyConfig(max_deviation_m=0.3, hold_before_land_s=0.05)}
    )
    rig = Rig(policy, cfg)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "deviation" and "hold" in rig.commands()


async def test_a_pilot_taking_over_is_not_fought(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: rig.vehicle.set_mode("POSCTL"))
    assert s.stop_reason == "pilot_takeover"
    assert rig.commands() == ["arm", "offboard_start"]  # no hold, no land, no offboard restart
    n = len(rig.vehicle.setpoints)
    await asyncio.sleep(0.2)
    assert len(rig.vehicle.setpoints) == n  # streaming stopped


async def test_first_signal_holds_and_lands_second_forces_exit_after_hold(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    s = await rig.in_mission_then(lambda: rig.daemon.handle_signal(signal.SIGTERM))
    assert s.stop_reason == "operator_stop" and s.exit_code == 3
    assert rig.commands()[-2:] == ["hold", "land"]

    rig2 = Rig(forward_policy, fast_config(land_at_goal=True))
    rig2.daemon.cfg = FlightConfig(
        **{**rig2.daemon.cfg.__dict__, "safety": SafetyConfig(hold_before_land_s=5.0)}
    )

    def twice() -> None:
        rig2.daemon.handle_signal(signal.SIGINT)
        asyncio.get_running_loop().call_later(0.1, rig2.daemon.handle_signal, signal.SIGINT)

    s2 = await rig2.in_mission_then(twice)
    assert s2.stop_reason == "operator_stop"
    assert "hold" in rig2.commands() and "land" not in rig2.commands()


async def test_a_setpoint_speed_that_does_not_match_the_primitives_is_refused_before_arming(
    forward_policy: Policy,
) -> None:
    """0.25 m primitives every 0.25 s fly at 1 m/s; a 0.5 m/s moving setpoint is not what was trained."""
    rig = Rig(forward_policy, path=RoughPath(PATH.waypoints_m, 0.5))
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2
    assert "mission.speed_m_s 0.5" in s.detail and "1 m/s" in s.detail
    assert rig.commands() == []


async def test_a_model_that_reads_the_scale_is_flown_only_within_the_scales_it_reads(tmp_path: Path) -> None:
    """The fast config's 0.25 m primitives: refused for a lane read across 0.5-1 m, flown for one
    read across 0.25-1 m."""
    outside = constant_action_checkpoint(str(tmp_path / "r.pt"), FORWARD, NetworkConfig(
        scale_input=True, scale_range_m=(0.5, 1.0)))
    rig = Rig(Policy(outside))
    s = await asyncio.wait_for(rig.daemon.run(), 10)
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2
    assert "primitives.scale_m 0.25 is outside the scales the model reads, 0.5-1 m" in s.detail
    assert rig.commands() == []
    inside = constant_action_checkpoint(str(tmp_path / "i.pt"), FORWARD, NetworkConfig(
        scale_input=True, scale_range_m=(0.25, 1.0)))
    rig2 = Rig(Policy(inside))
    s2 = await rig2.in_mission_then(lambda: rig2.daemon.handle_signal(signal.SIGINT))
    assert s2.stop_reason == "operator_stop" and "arm" in rig2.commands()


async def test_a_model_of_the_wrong_shape_is_refused_before_arming(tmp_path: Path) -> None:
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / "five.pt", DQN(NetworkConfig(n_actions=5)))
    rig = Rig(Policy(load_checkpoint(path)))
    s = await asyncio.wait_for(rig.daemon.run(), 10)
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2 and "model" in s.detail
    assert rig.commands() == []


async def test_nan_odometry_is_refused_before_arming(forward_policy: Policy) -> None:
    rig = Rig(forward_policy, FlightConfig(**{**fast_config().__dict__}))
    rig.odom.nan = True
    rig.daemon.cfg = FlightConfig(
        **{**rig.daemon.cfg.__dict__, "vehicle": type(rig.daemon.cfg.vehicle)(health_timeout_s=0.3)}
    )
    s = await asyncio.wait_for(rig.daemon.run(), 10)
    assert s.stop_reason == "preflight_failed" and "odometry" in s.detail and "NaN" in s.detail
    assert rig.commands() == []


async def test_all_invalid_depth_is_refused_before_arming(forward_policy: Policy) -> None:
    rig = Rig(forward_policy)
    rig.depth.depth_mm = 0
    rig.daemon.cfg = FlightConfig(
        **{**rig.daemon.cfg.__dict__, "vehicle": type(rig.daemon.cfg.vehicle)(health_timeout_s=0.3)}
    )
    s = await asyncio.wait_for(rig.daemon.run(), 10)
    assert s.stop_reason == "preflight_failed" and "depth" in s.detail
    assert rig.commands() == []


async def test_a_failing_recorder_never_breaks_the_flight(forward_policy: Policy) -> None:
    class Broken:
        def __getattr__(self, name: str):
            def boom(*a: object, **k: object) -> None:
                raise OSError("disk full")

            return boom

    rig = Rig(forward_policy, recorder=Broken())
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "goal_reached"


async def test_systemd_hears_ready_after_preflight_and_watchdog_pings(
    forward_policy: Policy, tmp_path: Path
) -> None:
    import socket

    from quadnav_onboard.sdnotify import SdNotifier

    sock_path = str(tmp_path / "notify.sock")
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    listener.bind(sock_path)
    listener.setblocking(False)
    got: list[str] = []
    loop = asyncio.get_running_loop()
    loop.add_reader(listener.fileno(), lambda: got.append(listener.recv(4096).decode()))  # like systemd
    rig = Rig(forward_policy, notifier=SdNotifier(sock_path, watchdog_timeout_s=0.2))
    try:
        s = await asyncio.wait_for(rig.daemon.run(), 15)
    finally:
        loop.remove_reader(listener.fileno())
        listener.close()
    assert s.stop_reason == "goal_reached"
    ready = [i for i, m in enumerate(got) if "READY=1" in m]
    pings = [i for i, m in enumerate(got) if m == "WATCHDOG=1"]
    assert len(ready) == 1 and len(pings) >= 5  # a ~2 s flight at one ping per 0.1 s
    assert any(i > ready[0] for i in pings)


async def test_a_pilots_switch_to_offboard_is_the_go_and_is_not_repeated(forward_policy: Policy) -> None:
    from quadnav_onboard.trigger import MissionTriggerConfig

    trigger = parse_config(MissionTriggerConfig, {"mode": "offboard_switch"})
    rig = Rig(forward_policy, trigger=trigger)
    streamed_before_switch: list[bool] = []

    async def pilot() -> None:
        await rig.when(lambda: rig.daemon.phase == "wait_for_go")
        await asyncio.sleep(0.3)
        assert rig.commands() == []  # nothing armed while waiting
        streamed_before_switch.append(len(rig.vehicle.setpoints) > 0)
        rig.vehicle.state.armed = True  # the pilot arms ...
        rig.vehicle.set_mode("OFFBOARD")  # ... and flips the switch

    task = asyncio.ensure_future(pilot())
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    await task
    assert streamed_before_switch == [True]  # PX4 needs a live stream to accept OFFBOARD
    assert s.stop_reason == "goal_reached"
    assert "arm" not in rig.commands() and "offboard_start" not in rig.commands()


async def test_a_camera_that_cannot_open_is_a_refusal_and_nothing_arms(forward_policy: Policy) -> None:
    """A sensor failing to open is a pre-flight refusal (exit 2), not an internal error."""

    class BrokenCamera(FakeDepthSource):
        async def __aenter__(self):  # type: ignore[override]
            raise OSError("/dev/video9: no such device")

    rig = Rig(forward_policy)
    rig.daemon.depth_source = BrokenCamera(fps=30.0)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2
    assert "/dev/video9" in s.detail
    assert "arm" not in rig.commands()


async def test_inputs_are_checked_again_at_the_go_before_arming(
    forward_policy: Policy, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A camera that dies between preflight and the go is caught before arming: nothing arms."""
    import types

    import quadnav_onboard.trigger as trigger_mod

    rig = Rig(forward_policy)

    async def go_after_camera_died(*_a: object, **_k: object) -> types.SimpleNamespace:
        rig.depth.paused = True
        await asyncio.sleep(fast_config().safety.stale_depth_s + 0.2)
        return types.SimpleNamespace(mode="socket", detail="GO")

    monkeypatch.setattr(trigger_mod, "wait_for_go", go_after_camera_died)
    rig.daemon.trigger = types.SimpleNamespace(mode="socket")
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "preflight_failed" and s.exit_code == 2
    assert "depth" in s.detail
    assert "arm" not in rig.commands()


async def test_the_heap_is_frozen_for_the_flight_and_released_after(forward_policy: Policy) -> None:
    """A full collection in flight walks only what the flight allocated (gc.freeze after preflight:
    a 150 ms pause becomes < 1 ms, benchmarks/bench_daemon.py --full-gc-mid-flight); a process that
    goes on afterwards collects as before."""
    import gc

    rig = Rig(forward_policy)
    frozen_in_flight: list[int] = []
    s = await rig.in_mission_then(lambda: frozen_in_flight.append(gc.get_freeze_count()), min_steps=2)
    assert s.stop_reason == "goal_reached"
    assert frozen_in_flight and frozen_in_flight[0] > 10_000  # torch, numpy, the model: all frozen
    assert gc.get_freeze_count() == 0


def test_bench_daemon_thread_cpu_names_the_thread_that_worked() -> None:
    """benchmarks/bench_daemon.py's CPU by thread (docs/daemon.md): a named thread that spins until
    it is sampled shows up under its name, with the CPU it had used by the last sample taken while it
    lived; an idle one does not."""
    import sys
    import threading

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    import bench_daemon

    cpu = bench_daemon.ThreadCpu()
    t0 = time.monotonic()
    sampled = threading.Event()

    def spin() -> None:  # until the sample below is taken (a wall-clock end races a starved main thread)
        while not sampled.is_set():
            pass

    busy = threading.Thread(target=spin, name="busy-bench")
    idle = threading.Thread(target=sampled.wait, name="idle-bench")
    for t in (busy, idle):
        t.start()
    time.sleep(0.4)
    cpu.sample()  # while both live: their names and CPU so far
    sampled.set()
    for t in (busy, idle):
        t.join()
    cpu.sample()  # both gone: they keep the last sample
    by_name = cpu.fractions(time.monotonic() - t0)
    assert by_name["busy-bench"] > 0.1
    assert by_name.get("idle-bench", 0.0) < 0.05


class FlakyVisionVehicle(FakeVehicle):
    """Vision forwards fail as ``fails(n)`` says for the n-th forward (as MAVSDK's MocapError does,
    seen through the vehicle link: a VehicleError of kind NOT_SENT)."""

    def __init__(self, fails) -> None:
        super().__init__()
        self.fails = fails
        self.forwards = 0

    async def send_vision_position(self, pos_world_m, quat_world_body, t_mono_s) -> None:
        self.forwards += 1
        if self.fails(self.forwards):
            raise VehicleError("vision estimate: not sent: CONNECTION_ERROR", VehicleErrorKind.NOT_SENT)
        self._log("vision")


def forwarding_config() -> FlightConfig:
    cfg = fast_config()
    return dataclasses.replace(cfg, odometry=OdometrySourceConfig(kind="mocap", forward_to_px4=True))


async def test_failed_vision_forwards_are_counted_and_the_flight_goes_on(forward_policy: Policy) -> None:
    vehicle = FlakyVisionVehicle(lambda n: n % 10 == 0)  # one in ten fails
    rig = Rig(forward_policy, forwarding_config(), vehicle=vehicle)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "goal_reached", s
    assert s.vision_forwards["failed"] == vehicle.forwards // 10 > 0
    assert s.vision_forwards["sent"] == vehicle.forwards - s.vision_forwards["failed"]


async def test_a_sustained_vision_forward_failure_stops_the_flight(forward_policy: Policy) -> None:
    vehicle = FlakyVisionVehicle(lambda n: False)
    rig = Rig(forward_policy, forwarding_config(), vehicle=vehicle)
    s = await rig.in_mission_then(lambda: setattr(vehicle, "fails", lambda n: True), min_steps=2)
    assert s.stop_reason == "vision_forward_failed" and s.exit_code == 3, s
    assert rig.commands()[-2:] == ["hold", "land"]
    assert rig.daemon.stats.odometry_samples > vehicle.forwards - s.vision_forwards["sent"]  # ingest went on


async def test_a_dead_link_with_odometry_on_it_is_link_lost_and_nothing_is_commanded(
    forward_policy: Policy,
) -> None:
    """Odometry dies with the link: stale odometry is seen first, but the stop is link_lost, and
    neither hold nor land is sent into the dead link."""
    rig = Rig(forward_policy)

    def cut() -> None:
        rig.vehicle.link_up = False
        rig.odom.paused = True

    s = await rig.in_mission_then(cut, min_steps=2)
    assert s.stop_reason == "link_lost" and s.exit_code == 3, s
    assert rig.commands() == ["arm", "offboard_start"]
    assert rig.daemon.stats.stops_deferred_for_link == 1


async def test_a_link_that_comes_back_gets_the_stop_it_was_holding(forward_policy: Policy) -> None:
    """A short silence with stale odometry: the stop waits for the link, which comes back; the
    stop is then the stale odometry, with the ladder."""
    rig = Rig(forward_policy)

    async def blip() -> None:
        rig.vehicle.link_up = False
        rig.odom.paused = True
        await rig.when(lambda: rig.daemon.deferred_stop is not None)
        rig.vehicle.link_up = True

    s = await rig.in_mission_then(lambda: asyncio.ensure_future(blip()), min_steps=2)
    assert s.stop_reason == "stale_odometry", s
    assert rig.commands()[-2:] == ["hold", "land"]


async def test_a_link_that_falls_silent_during_the_hold_gets_no_land(forward_policy: Policy) -> None:
    """Stale depth: hold; the link then dies during the hold: land is not sent and no land timeout
    is waited out; the stop stays the one that started the ladder."""
    cfg = fast_config()
    cfg = dataclasses.replace(cfg, safety=dataclasses.replace(cfg.safety, hold_before_land_s=1.0))
    rig = Rig(forward_policy, cfg)

    async def cut_at_hold() -> None:
        rig.depth.paused = True
        await rig.when(lambda: "hold" in rig.commands())
        rig.vehicle.link_up = False

    s = await rig.in_mission_then(lambda: asyncio.ensure_future(cut_at_hold()), min_steps=2)
    assert s.stop_reason == "stale_depth", s
    assert rig.commands()[-1] == "hold" and "land" not in rig.commands()


async def test_a_vehicle_that_disarmed_during_the_hold_is_not_landed(forward_policy: Policy) -> None:
    cfg = fast_config()
    cfg = dataclasses.replace(cfg, safety=dataclasses.replace(cfg.safety, hold_before_land_s=0.5))
    rig = Rig(forward_policy, cfg)

    async def disarm_at_hold() -> None:
        rig.depth.paused = True
        await rig.when(lambda: "hold" in rig.commands())
        rig.vehicle.state.armed = False  # a crash, or the pilot's kill switch

    s = await rig.in_mission_then(lambda: asyncio.ensure_future(disarm_at_hold()), min_steps=2)
    assert s.stop_reason == "stale_depth", s
    assert rig.commands()[-1] == "hold"


def test_odometry_speed_is_displacement_over_arrival_time_between_samples_20_ms_apart() -> None:
    """The take-off's settle test reads the speed from positions alone (a mocap gives no
    velocity): infinite until two samples, samples closer than 20 ms in time keep the last
    estimate, and a vehicle at rest reads zero."""
    from quadnav_onboard.daemon.app import OdometrySpeed
    from quadnav_onboard.sources.base import OdometrySample

    def at(t: float, x: float) -> OdometrySample:
        return OdometrySample(np.array([x, 0.0, 1.0]), np.array([1.0, 0.0, 0.0, 0.0]), t)

    speed = OdometrySpeed()
    assert speed.update(at(0.0, 0.0)) == float("inf")
    assert speed.update(at(0.01, 0.5)) == float("inf")  # 10 ms: too close to measure
    assert speed.update(at(0.1, 0.05)) == pytest.approx(0.5)  # 5 cm in 0.1 s
    assert speed.update(at(0.2, 0.05)) == pytest.approx(0.0)
    assert speed.update(at(0.21, 9.0)) == pytest.approx(0.0)  # kept until 20 ms have passed


def test_odometry_speed_counts_how_long_the_vehicle_has_stayed_slow() -> None:
    """Settled means slow for a while, not slow at one sample pair: a swing reads slow at its
    turns, and one fast estimate starts the count again."""
    from quadnav_onboard.daemon.app import OdometrySpeed
    from quadnav_onboard.sources.base import OdometrySample

    def at(t: float, x: float) -> OdometrySample:
        return OdometrySample(np.array([x, 0.0, 1.0]), np.array([1.0, 0.0, 0.0, 0.0]), t)

    speed = OdometrySpeed()
    assert speed.slow_for(at(0.0, 0.0), 0.2) == 0.0  # no estimate yet
    assert speed.slow_for(at(0.1, 0.0), 0.2) == 0.0  # slow from here
    assert speed.slow_for(at(0.4, 0.01), 0.2) == pytest.approx(0.3)
    assert speed.slow_for(at(0.5, 0.1), 0.2) == 0.0  # 0.9 m/s
    assert speed.slow_for(at(0.6, 0.1), 0.2) == 0.0
    assert speed.slow_for(at(0.7, 0.1), 0.2) == pytest.approx(0.1)


def bobbing(rig: Rig, amplitude_m: float, hz: float) -> None:
    """The vehicle's reported position swings up and down about the fake's once it has climbed."""
    t0 = time.monotonic()

    def pose() -> np.ndarray:
        pos = rig.vehicle.pos_world_m.copy()
        if pos[2] > 0.5:
            pos[2] += amplitude_m * np.sin(2 * np.pi * hz * (time.monotonic() - t0))
        return pos

    rig.odom.pose_fn = pose


async def test_a_vehicle_swinging_about_the_start_does_not_start_the_mission(forward_policy: Policy) -> None:
    """A 5 cm, 3 Hz swing reads slow at each turn (every 0.17 s), but never stays slow for
    ``start_settled_for_s``: the take-off times out rather than start mid-swing."""
    rig = Rig(forward_policy, fast_config(takeoff_timeout_s=2.0))
    bobbing(rig, 0.05, 3.0)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.stop_reason == "takeoff_timeout", s
    assert s.steps == 0


async def test_the_same_swing_starts_when_the_speed_limit_allows_it(forward_policy: Policy) -> None:
    """The control for the test above: with the limit above the swing's 0.94 m/s peak the same
    rig flies (the timeout there is the settle rule's, not the rig's)."""
    rig = Rig(forward_policy, fast_config(takeoff_timeout_s=2.0, start_settled_speed_m_s=3.0))
    bobbing(rig, 0.05, 3.0)
    s = await asyncio.wait_for(rig.daemon.run(), 15)
    assert s.steps >= 1, s
