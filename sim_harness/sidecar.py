"""The sim's vehicle side, one process per part, as a real vehicle has them apart from the daemon.

    python -m sim_harness.sidecar vehicle --spec '{"world": "...", "truth": "...", "api_port": 14640}'
    python -m sim_harness.sidecar camera  --spec '{"world": "...", "truth": "...", "socket": "/run/x.sock"}'
    python -m sim_harness.sidecar mocap   --spec '{"truth": "...", "command_port": 1510, "data_port": 1511}'
    python -m sim_harness.sidecar bridge  --spec '{"world": "...", "truth": "...", "port": 14550}'

* ``vehicle``: the emulated PX4 (MAVLink 2 over UDP to ``api_port``); it owns the vehicle's true
  state and writes it into the shared truth block (:mod:`sim_harness.truth`) every physics tick.
* ``camera``: the synthetic D435: renders the world from the true pose on the frame-rate grid of
  the monotonic clock and sends each frame over a Unix socket
  (:mod:`quadnav_onboard.sources.socket_depth`), dropping frames the reader is not ready for.
* ``mocap``: an emulated OptiTrack Motive (NatNet 3.0, unicast; :mod:`sim_harness.natnet`)
  streaming the true pose, optionally with noise, latency and dropouts.
* ``bridge``: instead of ``vehicle``, when the vehicle is a PX4 SITL the user runs: listens
  (never sends) on a UDP port PX4 streams to (its GCS link, 14550 by default, or a MAVLink
  instance of its own, ``mavlink start -u 14582 -o 14541``) and writes PX4's own reported state
  into the truth block (:class:`sim_harness.px4.bridge.SitlBridge`), so the camera and mocap render
  from where PX4 says the vehicle is. Ready once PX4 reported a position.

Each part compiles (or loads from cache) its kernels, then prints one JSON line
``{"ready": true, ...}`` on stdout and logs to stderr; it exits on SIGTERM/SIGINT or when its
parent process goes away. :class:`sim_harness.vehicle_side.VehicleSide` starts these parts for
``quadnav-onboard --dry-run`` and ``quadnav-sim serve``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import math
import os
import select
import signal
import socket
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["GEAR_HEIGHT_M", "main", "set_on_signals"]

GEAR_HEIGHT_M = 0.1
"""The emulator parks the body origin on the floor; a real D435 sits at least landing-gear height
above it (else it sees no floor at all and preflight rightly refuses an all-invalid frame). The sim
camera's height is floored at ``floor + GEAR_HEIGHT_M``; in flight (higher) nothing changes."""


def set_on_signals(event: threading.Event,
                   signals: tuple[signal.Signals, ...] = (signal.SIGINT, signal.SIGTERM)) -> dict:
    """Install handlers that set ``event`` on ``signals``; returns the previous handlers. The set
    runs in a short thread, not in the handler: the handler runs in the main thread, which may
    hold the event's lock inside its own ``wait()``, and setting it there would deadlock."""
    return {s: signal.signal(s, lambda *_: threading.Thread(target=event.set, daemon=True).start())
            for s in signals}


class _Exit:
    """Set on SIGTERM/SIGINT or when the parent process is gone."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self._parent = os.getppid()
        set_on_signals(self.event)

    def due(self) -> bool:
        if os.getppid() != self._parent:
            self.event.set()
        return self.event.is_set()

    def wait(self, timeout_s: float) -> bool:
        return self.event.wait(timeout_s) or self.due()


def _ready(**info: Any) -> None:
    sys.stdout.write(json.dumps({"ready": True, "pid": os.getpid(), **info}) + "\n")
    sys.stdout.flush()


def _load_world(spec: dict[str, Any]) -> Any:
    from sim_harness.world import load_world

    return load_world(Path(spec["world"]))


# --- vehicle -------------------------------------------------------------------------------------


def run_vehicle(spec: dict[str, Any], stop: _Exit) -> int:
    from sim_harness.px4 import EmulatorConfig, Px4Emulator
    from sim_harness.px4.emulator import _collision_fn
    from sim_harness.truth import TruthBlock

    world = _load_world(spec)
    cfg = EmulatorConfig()
    if spec.get("emulator_config"):
        from quadnav_onboard.config import load_yaml_config

        cfg = load_yaml_config(EmulatorConfig, spec["emulator_config"])
    cfg = dataclasses.replace(cfg, **spec.get("emulator", {}))
    truth = TruthBlock.attach(spec["truth"])
    t0 = time.monotonic()
    collide = _collision_fn(world, cfg.quad.radius_m)  # compile (or load) the collision kernel now
    if collide is not None:
        p = np.zeros(3)
        collide(p, p)
    warm_s = time.monotonic() - t0
    emu = Px4Emulator(world, cfg, api_port=int(spec["api_port"]), gcs_port=spec.get("gcs_port"))

    def publish(pose: Any) -> None:
        v = emu.vehicle
        truth.write(pose.pos_world_m, pose.vel_world_m_s, pose.quat_world_body, pose.t_mono_s,
                    v.crashed, v.armed)

    emu.on_pose = publish
    emu.start()
    if spec.get("scenario"):
        from sim_harness.px4.scenario import apply_scenario, load_scenario

        apply_scenario(emu.faults, load_scenario(spec["scenario"]))
    _ready(role="vehicle", api_port=emu.api_port, warm_s=round(warm_s, 3),
           start_m=[round(float(v), 3) for v in emu.true_pose().pos_world_m])
    from quadnav_onboard.logs import get_logger

    log = get_logger("quadnav-sim.vehicle")
    seen = 0
    try:
        while not stop.wait(0.2):
            events = emu.events
            for t, kind, message in events[seen:]:
                log.info("vehicle_event", kind=kind, message=message, t_mono_s=round(t, 3))
            seen = len(events)
    finally:
        emu.stop()
        truth.close()
    return 0


# --- bridge (a PX4 SITL's reported state as the truth) ------------------------------------------


def run_bridge(spec: dict[str, Any], stop: _Exit) -> int:
    from quadnav_onboard.logs import get_logger
    from sim_harness.px4.bridge import SitlBridge
    from sim_harness.px4.emulator import _collision_fn
    from sim_harness.px4.mavlink_io import mavlink2
    from sim_harness.quad import QuadParams
    from sim_harness.truth import TruthBlock

    log = get_logger("quadnav-sim.bridge")
    world = _load_world(spec)
    collide = _collision_fn(world, QuadParams().radius_m)
    if collide is not None:  # compile (or load) the collision kernel now
        collide(np.zeros(3), np.zeros(3))
    bridge = SitlBridge(world.floor_z_m or 0.0, system_id=spec.get("system_id"), collide=collide)
    truth = TruthBlock.attach(spec["truth"])
    host, port = str(spec.get("host", "127.0.0.1")), int(spec.get("port", 14550))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # no SO_REUSEADDR: never share a port
    try:
        sock.bind((host, port))
    except OSError as exc:
        log.error("bridge_port_busy", host=host, port=port, error=str(exc),
                  hint="QGroundControl listens on 14550: close it, or give PX4 a MAVLink instance of "
                  "the bridge's own (sys_test/README.md)")
        return 3
    parser = mavlink2.MAVLink(None)
    parser.robust_parsing = True
    wait_s = float(spec.get("wait_s", 60.0))
    t0 = time.monotonic()
    ready = False
    try:
        while not stop.due():
            readable, _, _ = select.select([sock], [], [], 0.2)
            if not ready and bridge.pose is None and time.monotonic() - t0 > wait_s:
                log.error("bridge_no_px4", host=host, port=port, waited_s=wait_s,
                          hint="start PX4 SITL (make px4_sitl sihsim_quadx) before the flight")
                return 3
            if not readable:
                continue
            data = sock.recv(65535)
            now = time.monotonic()
            try:
                messages = parser.parse_buffer(data) or []
            except mavlink2.MAVError:
                continue
            for msg in messages:
                if msg.get_type() != "BAD_DATA" and bridge.on_message(msg, now):
                    p = bridge.pose
                    assert p is not None
                    truth.write(p.pos_world_m, p.vel_world_m_s, p.quat_world_body, p.t_mono_s,
                                bridge.crashed, bridge.armed)
            if not ready and bridge.pose is not None:
                ready = True
                _ready(role="bridge", port=port, system_id=bridge.system_id,
                       start_m=[round(float(v), 3) for v in bridge.pose.pos_world_m],
                       ground_up_m=round(float(bridge.ground_up_m or 0.0), 3))
    finally:
        sock.close()
        truth.close()
    return 0


# --- camera --------------------------------------------------------------------------------------


def run_camera(spec: dict[str, Any], stop: _Exit) -> int:
    from sim_harness.render import CameraModel, render_frame_mm
    from sim_harness.truth import TruthBlock

    world = _load_world(spec)
    truth = TruthBlock.attach(spec["truth"])
    camera = CameraModel(width=int(spec.get("width", 424)), height=int(spec.get("height", 240)))
    fps = float(spec.get("fps", 30.0))
    noise = None
    rng = np.random.default_rng(int(spec.get("seed", 0)))
    if spec.get("noise"):
        from sim_harness.noise import DepthNoise

        noise = DepthNoise()
    min_z = (world.floor_z_m or 0.0) + GEAR_HEIGHT_M

    def render(state: Any) -> np.ndarray:
        pos = np.array(state.pos_world_m, dtype=np.float64)
        pos[2] = max(pos[2], min_z)
        return render_frame_mm(world, pos, state.quat_world_body, camera, noise=noise,
                               rng=rng if noise is not None else None)

    t0 = time.monotonic()
    render(truth.read())  # compile (or load) the render kernels before anyone connects
    warm_s = time.monotonic() - t0
    path = spec["socket"]
    with _listen_unix(path) as server:
        _ready(role="camera", socket=path, width=camera.width, height=camera.height, fps=fps,
               warm_s=round(warm_s, 3))
        while not stop.due():
            readable, _, _ = select.select([server], [], [], 0.2)
            if not readable:
                continue
            conn, _ = server.accept()
            with conn:
                _stream(conn, render, truth, fps, stop)
    truth.close()
    return 0


class _listen_unix:
    def __init__(self, path: str) -> None:
        self.path = path

    def __enter__(self) -> socket.socket:
        if os.path.exists(self.path):
            os.unlink(self.path)
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        self.sock.bind(self.path)
        self.sock.listen(1)
        return self.sock

    def __exit__(self, *exc: object) -> None:
        self.sock.close()
        if os.path.exists(self.path):
            os.unlink(self.path)


def _stream(conn: socket.socket, render: Any, truth: Any, fps: float, stop: _Exit) -> None:
    """Frames on the ``fps`` grid until the reader goes away; a frame the reader has no room for
    is dropped (latest wins), never queued."""
    from quadnav_onboard.logs import get_logger
    from quadnav_onboard.sources.socket_depth import encode_frame

    log = get_logger("quadnav-sim.camera")
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 2 * 424 * 240 * 2)
    period = 1.0 / fps
    t0 = time.monotonic()
    k, sent, dropped = 0, 0, 0
    while not stop.due():
        k = max(k + 1, math.floor((time.monotonic() - t0) / period) + 1)
        t_capture = t0 + k * period
        if stop.wait(max(0.0, t_capture - time.monotonic())):
            break
        frame = render(truth.read())
        _, writable, _ = select.select([], [conn], [], 0.0)
        if not writable:
            dropped += 1
            continue
        header, pixels = encode_frame(frame, k, t_capture)
        try:
            conn.sendall(header)
            conn.sendall(pixels)
        except OSError:  # the reader went away
            break
        sent += 1
    log.info("camera_stream_ended", sent=sent, dropped=dropped)


# --- mocap ---------------------------------------------------------------------------------------


def run_mocap(spec: dict[str, Any], stop: _Exit) -> int:
    from quadnav_onboard.frames import quat_from_yaw, quat_multiply
    from sim_harness.natnet import NatNetCommandServer, frame_of_data, world_to_motive
    from sim_harness.truth import TruthBlock

    truth = TruthBlock.attach(spec["truth"])
    body = str(spec.get("rigid_body", "quad"))
    rate_hz = float(spec.get("rate_hz", 120.0))
    noise_m = float(spec.get("noise_m", 0.0))
    noise_rad = float(spec.get("noise_rad", 0.0))
    latency_s = float(spec.get("latency_s", 0.0))
    dropout = float(spec.get("dropout", 0.0))
    rng = np.random.default_rng(int(spec.get("seed", 0)))
    host = str(spec.get("host", "127.0.0.1"))
    server = NatNetCommandServer(host, int(spec["command_port"]), int(spec["data_port"]), [(body, 1)])
    out = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    _ready(role="mocap", host=host, command_port=server.command_port, data_port=server.data_port,
           rigid_body=body, rate_hz=rate_hz)
    pending: deque[tuple[float, bytes]] = deque()
    period = 1.0 / rate_hz
    t0 = time.monotonic()
    k = 0
    try:
        while not stop.due():
            k = max(k + 1, math.floor((time.monotonic() - t0) / period) + 1)
            t_tick = t0 + k * period
            # Answer requests while waiting for the tick.
            while True:
                wait = t_tick - time.monotonic()
                if wait <= 0:
                    break
                select.select([server.sock], [], [], wait)
                server.poll()
            server.poll()
            state = truth.read()
            now = time.monotonic()
            tracked = bool(np.isfinite(state.t_mono_s)) and rng.random() >= dropout
            pos = np.array(state.pos_world_m, dtype=np.float64)
            q = np.array(state.quat_world_body, dtype=np.float64)
            if noise_m > 0:
                pos = pos + rng.normal(0.0, noise_m, 3)
            if noise_rad > 0:
                q = quat_multiply(quat_from_yaw(rng.normal(0.0, noise_rad)), q)
            pos_m, q_m = world_to_motive(pos, q)
            packet = frame_of_data(k, [(1, pos_m, q_m, tracked)], int((now - t0) * 1e6))
            pending.append((now + latency_s, packet))
            while pending and pending[0][0] <= time.monotonic():
                _, data = pending.popleft()
                for client in server.clients:
                    with contextlib.suppress(OSError):  # nobody listening there: UDP, like Motive
                        out.sendto(data, client)
    finally:
        server.close()
        out.close()
        truth.close()
    return 0


_ROLES = {"vehicle": run_vehicle, "camera": run_camera, "mocap": run_mocap, "bridge": run_bridge}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m sim_harness.sidecar", description=__doc__.split("\n")[0])
    parser.add_argument("role", choices=sorted(_ROLES))
    parser.add_argument("--spec", required=True, help="JSON object: the part's settings")
    args = parser.parse_args(argv)
    from quadnav_onboard.logs import configure_logging

    configure_logging(json=True)
    stop = _Exit()
    return _ROLES[args.role](json.loads(args.spec), stop)


if __name__ == "__main__":
    sys.exit(main())
