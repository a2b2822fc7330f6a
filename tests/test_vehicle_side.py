"""The sim's vehicle side as separate processes: the truth block, the depth socket, the emulated
Motive read through the real motioncapture library, and the daemon flying against them while a
part dies."""

from __future__ import annotations

import asyncio
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.daemon.app import FlightDaemon
from quadnav_onboard.daemon.config import FlightConfig, MissionConfig, SafetyConfig, default_sim_config
from quadnav_onboard.daemon.dryrun import ProcessDryRun
from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.policy import Policy
from quadnav_onboard.sources.mocap import MocapError, MocapOdometrySource, MocapTransform, probe_natnet
from quadnav_onboard.sources.socket_depth import DepthWireError, SocketDepthSource, encode_frame
from sim_harness.natnet import ROTATION_WORLD_FROM_MOTIVE, world_to_motive
from sim_harness.px4.ports import free_udp_port
from sim_harness.truth import TruthBlock
from sim_harness.vehicle_side import VehicleSide


@pytest.fixture(scope="module")
def world(tmp_path_factory: pytest.TempPathFactory, straight_world: Callable[[Path, float], Path]) -> Path:
    return straight_world(tmp_path_factory.mktemp("w"), 6.0)


@pytest.fixture(scope="module")
def model(forward_model: Path) -> Path:
    return forward_model


# --- the truth block -------------------------------------------------------------------------------


def test_truth_block_reads_what_was_written_from_an_attached_view() -> None:
    block = TruthBlock.create()
    try:
        view = TruthBlock.attach(block.name)
        assert not np.isfinite(view.read().t_mono_s)  # nothing written yet
        q = quat_from_yaw(0.3)
        block.write(np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.0, 0.0]), q, 12.5, crashed=True, armed=True)
        s = view.read()
        assert np.allclose(s.pos_world_m, [1, 2, 3]) and np.allclose(s.quat_world_body, q)
        assert s.t_mono_s == 12.5 and s.crashed and s.armed
        view.close()
    finally:
        block.close()
    with pytest.raises(FileNotFoundError):
        TruthBlock.attach(block.name)  # the creator removed it


# --- depth frames over a Unix socket -------------------------------------------------------------


def _serve_frames(path: str, frames: list[np.ndarray], ready: threading.Event) -> None:
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as server:
        server.bind(path)
        server.listen(1)
        ready.set()
        conn, _ = server.accept()
        with conn:
            for k, frame in enumerate(frames):
                header, pixels = encode_frame(frame, k + 7, 100.0 + k)
                conn.sendall(header)
                conn.sendall(pixels)


async def test_socket_depth_source_delivers_frames_with_their_capture_time_then_ends(tmp_path: Path) -> None:
    path = str(tmp_path / "d.sock")
    frames = [np.full((40, 48), 1000 * (k + 1), np.uint16) for k in range(3)]
    ready = threading.Event()
    threading.Thread(target=_serve_frames, args=(path, frames, ready), daemon=True).start()
    ready.wait(5)
    got = []
    async with SocketDepthSource(path, 48, 40, connect_timeout_s=5) as src:
        with pytest.raises(ConnectionError, match="closed"):
            async for f in src.frames():
                got.append(f)
    assert [f.seq for f in got] == [7, 8, 9] and [f.t_capture_mono_s for f in got] == [100.0, 101.0, 102.0]
    assert all(np.array_equal(f.depth_mm, frames[k]) for k, f in enumerate(got))
    assert got[0].depth_mm.flags.writeable  # kernels downstream are warmed with writeable arrays


async def test_socket_depth_source_refuses_frames_of_another_size(tmp_path: Path) -> None:
    path = str(tmp_path / "d.sock")
    ready = threading.Event()
    threading.Thread(target=_serve_frames, args=(path, [np.zeros((40, 48), np.uint16)], ready),
                     daemon=True).start()
    ready.wait(5)
    async with SocketDepthSource(path, 424, 240, connect_timeout_s=5) as src:
        with pytest.raises(DepthWireError, match=r"48x40 frames .* configured 424x240"):
            await anext(src.frames())


async def test_socket_depth_source_names_the_path_when_no_camera_listens(tmp_path: Path) -> None:
    path = str(tmp_path / "none.sock")
    with pytest.raises(ConnectionError, match=r"no camera process listening at .*none\.sock"):
        async with SocketDepthSource(path, 424, 240, connect_timeout_s=0.2):
            pass


# --- the emulated Motive, through the real motioncapture library ---------------------------------


def test_motive_frame_maps_back_into_the_world_frame() -> None:
    pos, q = np.array([1.0, -2.0, 1.5]), quat_from_yaw(0.7)
    pos_m, q_m = world_to_motive(pos, q)
    assert np.isclose(pos_m[1], 1.5)  # y is up in Motive's frame
    back_pos, back_q = MocapTransform(ROTATION_WORLD_FROM_MOTIVE, (0, 0, 0)).apply(pos_m, q_m)
    assert np.allclose(back_pos, pos) and np.allclose(np.abs(back_q), np.abs(q))


def test_natnet_probe_refuses_with_the_address_when_nobody_answers() -> None:
    port = free_udp_port()
    with pytest.raises(MocapError, match=rf"no NatNet server answers at 127\.0\.0\.1:{port}"):
        probe_natnet("127.0.0.1", port, 0.2)


async def test_mocap_source_reads_the_emulated_motive_through_the_library(world: Path) -> None:
    with VehicleSide(world, parts=("vehicle", "mocap")) as side:
        host, port = side.mocap_command
        assert probe_natnet(host, port, 2.0) == "3.0.0.0"
        tf = MocapTransform(ROTATION_WORLD_FROM_MOTIVE, (0, 0, 0))
        src = MocapOdometrySource("optitrack", host, "quad", tf, port_command=port)
        async with src:
            samples = src.samples()
            first = await asyncio.wait_for(anext(samples), 5)
            for _ in range(20):
                last = await asyncio.wait_for(anext(samples), 1)
        truth = side.truth.read()  # type: ignore[union-attr]
    assert np.allclose(first.pos_world_m, truth.pos_world_m, atol=1e-5)  # on the ground at the start
    assert np.allclose(np.abs(last.quat_world_body), np.abs(truth.quat_world_body), atol=1e-5)
    assert last.t_arrival_mono_s > first.t_arrival_mono_s


def test_a_part_that_cannot_start_is_reported_with_its_log(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\n")
    with pytest.raises(RuntimeError, match=r"sim vehicle: exited with code \d+ before it was ready.*log"):
        VehicleSide(bad, parts=("vehicle",), ready_timeout_s=60).start()


# --- the daemon against the vehicle side, a part dying mid-flight --------------------------------


def _config(**safety: float) -> FlightConfig:
    """The dry run's sections (socket depth, NatNet mocap, the flight config's stale limits: 0.1 s
    odometry, 0.3 s depth) with 0.5 m primitives; ``safety`` overrides (a fault test widens the
    limit of the input it does not cut, so a loaded test machine cannot stop it for that one)."""
    base = default_sim_config()
    prims = parse_config(PrimitiveConfig, {"scale_m": 0.5, "duration_s": 0.5})
    limits = {"stale_odometry_s": base.safety.stale_odometry_s, "stale_depth_s": base.safety.stale_depth_s}
    return FlightConfig(
        mission=MissionConfig(takeoff_speed_m_s=2.0, max_steps=30),
        primitives=prims,
        safety=SafetyConfig(hold_before_land_s=0.3, land_timeout_s=15.0, **{**limits, **safety}),
        depth=base.depth,
        odometry=base.odometry,
        record=base.record.__class__(enabled=False),
    )


async def _fly(
    world: Path, model: Path, fault: Callable[[ProcessDryRun], None] | None, cfg: FlightConfig | None = None
) -> tuple[Any, Any]:
    with ProcessDryRun(cfg or _config(), world, emulator={"heartbeat_hz": 10.0}) as sim:
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(model), **sim.parts())

        async def inject() -> None:
            while not (daemon.in_mission and daemon.steps >= 2):
                await asyncio.sleep(0.02)
            fault(sim)  # type: ignore[misc]

        task = asyncio.ensure_future(inject()) if fault else None
        summary = await asyncio.wait_for(daemon.run(), 90)
        if task:
            task.cancel()
        return summary, sim


@pytest.mark.e2e
@pytest.mark.slow
async def test_dry_run_against_the_vehicle_side_reaches_the_goal(world: Path, model: Path) -> None:
    s, _ = await _fly(world, model, None)
    assert s.stop_reason == "goal_reached" and s.exit_code == 0, s
    assert s.startup["kernels_compiled_in_flight"] == {} and s.startup["warmup_s"] is not None


@pytest.mark.e2e
@pytest.mark.slow
async def test_dry_run_on_px4s_own_estimate_starts_no_mocap(world: Path, model: Path) -> None:
    import dataclasses

    base = _config()
    cfg = dataclasses.replace(base, odometry=dataclasses.replace(base.odometry, kind="px4"))
    s, sim = await _fly(world, model, None, cfg)
    assert set(sim.side.parts) == {"vehicle", "camera"} and sim.cfg.odometry.kind == "px4"
    assert s.stop_reason == "goal_reached", s


@pytest.mark.e2e
@pytest.mark.slow
async def test_mocap_process_dying_stops_for_stale_odometry(world: Path, model: Path) -> None:
    s, _ = await _fly(world, model, lambda sim: sim.side.kill("mocap"), _config(stale_depth_s=1.0))
    assert s.stop_reason == "stale_odometry" and s.exit_code == 3, s
    assert s.hold_reaction_ms is not None  # the hold was commanded (its time: benchmarks/)


@pytest.mark.e2e
@pytest.mark.slow
async def test_camera_process_dying_stops_for_stale_depth(world: Path, model: Path) -> None:
    s, _ = await _fly(world, model, lambda sim: sim.side.kill("camera"), _config(stale_odometry_s=0.5))
    assert s.stop_reason == "stale_depth" and s.exit_code == 3, s


@pytest.mark.e2e
@pytest.mark.slow
async def test_vehicle_process_dying_is_a_lost_link(world: Path, model: Path) -> None:
    s, _ = await _fly(world, model, lambda sim: sim.side.kill("vehicle"))
    assert s.stop_reason == "link_lost", s


@pytest.mark.slow
def test_stop_ends_every_part(world: Path) -> None:
    side = VehicleSide(world).start()
    pids = [p.process.pid for p in side.parts.values()]
    side.stop()
    for pid in pids:
        with pytest.raises(ProcessLookupError):
            os.kill(pid, 0)


@pytest.mark.slow
def test_parts_exit_when_the_process_that_started_them_is_killed(world: Path, tmp_path: Path) -> None:
    code = (
        "import sys, time\n"
        "from sim_harness.vehicle_side import VehicleSide\n"
        f"side = VehicleSide({str(world)!r}, parts=('vehicle', 'mocap')).start()\n"
        "print(*[p.process.pid for p in side.parts.values()], flush=True)\n"
        "time.sleep(60)\n"
    )
    parent = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True,
                              env={**os.environ, "TMPDIR": str(tmp_path)})  # its run dir, left behind
    assert parent.stdout is not None
    pids = [int(v) for v in parent.stdout.readline().split()]
    assert len(pids) == 2
    parent.kill()
    parent.wait()
    deadline = time.monotonic() + 10
    alive = pids
    while alive and time.monotonic() < deadline:
        alive = [pid for pid in alive if _alive(pid)]
        time.sleep(0.1)
    assert not alive


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has exited
    except FileNotFoundError:
        return False


# --- the daemon as on a vehicle, against a standalone `quadnav-sim serve` -------------------------


@pytest.mark.e2e
@pytest.mark.slow
def test_daemon_with_config_serve_flies_a_standalone_serve_after_the_go(world: Path, tmp_path: Path) -> None:
    import yaml

    repo = Path(__file__).resolve().parents[1]
    run_dir = tmp_path / "run"
    api_port, mocap_port = free_udp_port(), free_udp_port()
    cfg = yaml.safe_load((repo / "config" / "serve.yaml").read_text())
    cfg["mission"]["waypoints_m"] = [[0.0, 0.0, 1.5], [6.0, 0.0, 1.5]]
    cfg["vehicle"]["url"] = f"udpin://127.0.0.1:{api_port}"
    cfg["depth"]["socket_path"] = str(run_dir / "depth.sock")
    cfg["odometry"]["port_command"] = mocap_port
    cfg["trigger"]["socket_path"] = str(tmp_path / "go.sock")
    cfg["record"]["directory"] = str(tmp_path / "records")
    config = tmp_path / "serve.yaml"
    config.write_text(yaml.safe_dump(cfg))
    serve = subprocess.Popen(
        [sys.executable, "-m", "sim_harness.cli", "serve", "--world", str(world), "--api-port", str(api_port),
         "--mocap-port", str(mocap_port), "--run-dir", str(run_dir), "--heartbeat-hz", "10"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    try:
        assert serve.stdout is not None
        lines = [serve.stdout.readline() for _ in range(4)]
        if serve.poll() is not None:
            err = serve.stderr.read()[-2000:] if serve.stderr else ""
            pytest.fail(f"serve exited {serve.returncode}: {err}")
        assert any(f"udpin://0.0.0.0:{api_port}" in line for line in lines), lines
        daemon = subprocess.Popen(
            [sys.executable, "-m", "quadnav_onboard.cli", "--config", str(config), "--json"],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        try:
            go = str(tmp_path / "go.sock")
            deadline = time.monotonic() + 60
            answer = None
            while time.monotonic() < deadline and daemon.poll() is None:
                out = subprocess.run([sys.executable, "-m", "quadnav_onboard.trigger", "GO", "--socket", go],
                                     capture_output=True, text=True, check=False)
                if out.returncode == 0:
                    answer = out.stdout
                    break
                time.sleep(0.5)
            assert answer is not None, daemon.stderr.read() if daemon.poll() is not None else "no go socket"
            out_text, err_text = daemon.communicate(timeout=120)
        finally:
            if daemon.poll() is None:
                daemon.kill()
    finally:
        serve.send_signal(signal.SIGINT)
        serve.communicate(timeout=20)
    import json

    summary = json.loads(out_text.strip().splitlines()[-1])
    assert daemon.returncode == 0 and summary["stop_reason"] == "goal_reached", err_text[-2000:]
    assert summary["startup"]["kernels_compiled_in_flight"] == {}
    assert list((tmp_path / "records").glob("*.mcap"))


@pytest.mark.e2e
@pytest.mark.slow
def test_first_dry_run_with_no_compiled_cache_reaches_the_goal(world: Path, tmp_path: Path) -> None:
    """Every kernel compiles from nothing (numba's cache pointed at an empty folder: no cache the
    package wrote is found), yet the flight reaches the goal and nothing compiles after arming."""
    import json

    cache = tmp_path / "numba-cache"
    cache.mkdir()
    out = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--world", str(world), "--json",
         "--no-record"],
        env={**os.environ, "NUMBA_CACHE_DIR": str(cache)}, capture_output=True, text=True, timeout=240,
        check=False,
    )
    summary = json.loads(out.stdout.strip().splitlines()[-1])
    assert out.returncode == 0 and summary["stop_reason"] == "goal_reached", out.stderr[-2000:]
    assert summary["startup"]["kernels_compiled_in_flight"] == {}
    assert summary["startup"]["ready_s"] > summary["startup"]["warmup_s"] > 0
    written = {p.parts[len(cache.parts)].split("_")[0] for p in cache.rglob("*.nbi")}
    assert {"quadnav", "sim"} <= written  # the daemon's and the sim's kernels were compiled here


@pytest.mark.e2e
@pytest.mark.slow
async def test_the_vehicle_side_in_processes_flies_the_row_the_single_process_wiring_flies(
    world: Path, model: Path
) -> None:
    """Same world, start and model: the same stop, steps, crash and (within timing) distance and
    reward, whether the sim's parts run in their own processes or in the daemon's. The mission
    starts from a settled hover in both (``mission.start_settled_speed_m_s``): measured in 5 pairs of
    flights the totals were 0.003-0.047 apart; the bound catches a one-step difference (~1)."""
    from quadnav_onboard.daemon.dryrun import DryRun

    split, _ = await _fly(world, model, None)
    with DryRun(_config(), world, emulator={"heartbeat_hz": 10.0}) as sim:
        daemon = FlightDaemon(sim.cfg, policy=Policy.from_path(model), **sim.parts())
        single = await asyncio.wait_for(daemon.run(), 90)
    outcome = (split.stop_reason, split.steps, split.crashed)
    assert outcome == (single.stop_reason, single.steps, single.crashed)
    assert abs(split.navigation_distance_m - single.navigation_distance_m) < 0.05
    assert abs(split.total_reward - single.total_reward) < 0.25
