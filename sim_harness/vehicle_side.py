"""Start and stop the sim's vehicle side: the emulated PX4, the sim camera and the sim mocap, each
its own process (:mod:`sim_harness.sidecar`), sharing the vehicle's true state through one
shared-memory block (:mod:`sim_harness.truth`).

    with VehicleSide(world_path) as side:
        side.url            # MAVSDK: udpin://127.0.0.1:<port>
        side.depth_socket   # the camera's Unix socket
        side.mocap_command  # (host, port) of the emulated Motive
        side.kill("mocap")  # a part dies mid-flight

The parts start together (the camera's render kernels are the slowest to warm) and each reports
ready on its stdout; each logs to ``<run dir>/<part>.log``. On exit every part gets SIGTERM, then
SIGKILL, and the shared block and socket are removed. A part also exits by itself when the process
that started it goes away.

With ``bridge=`` the vehicle is a PX4 SITL the user runs, not the emulator: the ``bridge`` part
takes its place and writes PX4's own reported state into the shared block, and the camera (and
mocap) render from it (``parts=("bridge", "camera")``; the daemon connects to the SITL itself).
"""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sim_harness.px4.ports import free_udp_port
from sim_harness.truth import TruthBlock

__all__ = ["BRIDGE_PART", "PART_NAMES", "Part", "VehicleSide", "VehicleSideError"]

PART_NAMES = ("vehicle", "camera", "mocap")
BRIDGE_PART = "bridge"
"""The part that stands in for ``vehicle`` when the vehicle is a PX4 SITL (see ``bridge=``)."""

_TICKS_S = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100


class VehicleSideError(RuntimeError):
    """A part did not start (the message carries the end of its log)."""


class StartCancelled(VehicleSideError):
    """The start was cancelled (a signal) before every part was ready."""


@dataclass
class Part:
    """One running part."""

    name: str
    process: subprocess.Popen[bytes]
    log_path: Path
    info: dict[str, Any] = field(default_factory=dict)
    """What the part printed when ready (ports, socket path, warm-up time)."""
    cpu_s: float | None = None
    """CPU time (user + system, s) the part used, read when it was stopped."""


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of a live process (Linux /proc), None if it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return (int(fields[11]) + int(fields[12])) / _TICKS_S


class VehicleSide:
    """The sim's vehicle-side processes for one world (a context manager)."""

    def __init__(
        self,
        world_path: str | Path,
        *,
        api_port: int | None = None,
        camera: dict[str, Any] | None = None,
        mocap: dict[str, Any] | None = None,
        emulator: dict[str, Any] | None = None,
        emulator_config: str | Path | None = None,
        scenario: str | Path | None = None,
        gcs_port: int | None = None,
        parts: tuple[str, ...] | None = None,
        ready_timeout_s: float = 180.0,
        run_dir: str | Path | None = None,
        bridge: dict[str, Any] | None = None,
    ) -> None:
        """``bridge``: settings of the bridge part (``port`` PX4 streams to, ``host``,
        ``system_id``, ``wait_s``): fly a PX4 SITL; ``parts`` then defaults to bridge + camera."""
        if parts is None:
            parts = (BRIDGE_PART, "camera") if bridge is not None else PART_NAMES
        head = BRIDGE_PART if bridge is not None else "vehicle"
        allowed = (head, *PART_NAMES[1:])
        unknown = set(parts) - set(allowed)
        if unknown or head not in parts:
            raise ValueError(f"parts must include {head!r} and be among {allowed}, got {parts}")
        self._bridge = dict(bridge) if bridge is not None else None
        self.world_path = Path(world_path).resolve()
        self.api_port = api_port if api_port is not None else free_udp_port()
        self._camera = dict(camera or {})
        self._mocap = dict(mocap or {})
        self._emulator = dict(emulator or {})
        self._emulator_config = str(emulator_config) if emulator_config is not None else None
        self._scenario = str(scenario) if scenario is not None else None
        self._gcs_port = gcs_port
        self._wanted = tuple(p for p in allowed if p in parts)
        self.ready_timeout_s = float(ready_timeout_s)
        self._own_run_dir = run_dir is None
        self.run_dir = Path(run_dir) if run_dir is not None else Path(tempfile.mkdtemp(prefix="quadnav-sim-"))
        self.truth: TruthBlock | None = None
        self._crashed = False
        self.parts: dict[str, Part] = {}
        self.t_ready_s = float("nan")
        """Seconds from start() until every part was ready."""

    # --- what the daemon connects to -----------------------------------------------------------
    @property
    def url(self) -> str:
        return f"udpin://127.0.0.1:{self.api_port}"

    @property
    def depth_socket(self) -> str:
        return str(self.parts["camera"].info["socket"])

    @property
    def mocap_command(self) -> tuple[str, int]:
        info = self.parts["mocap"].info
        return str(info["host"]), int(info["command_port"])

    def crashed(self) -> bool:
        """The sim's ground truth: did the vehicle hit something. A writer held up mid-write (a
        loaded machine can preempt it for tens of milliseconds) gets 0.2 s; past that the last
        answer stands (a crash, once read, stays true)."""
        if self.truth is None:
            return False
        with contextlib.suppress(TimeoutError):
            self._crashed = self._crashed or self.truth.read(timeout_s=0.2).crashed
        return self._crashed

    # --- lifecycle -----------------------------------------------------------------------------
    def __enter__(self) -> VehicleSide:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def specs(self) -> dict[str, dict[str, Any]]:
        assert self.truth is not None
        common = {"truth": self.truth.name}
        specs = {
            "vehicle": {**common, "world": str(self.world_path), "api_port": self.api_port,
                        "gcs_port": self._gcs_port, "emulator": self._emulator,
                        "emulator_config": self._emulator_config,
                        "scenario": self._scenario},
            "camera": {**common, "world": str(self.world_path),
                       "socket": str(self.run_dir / "depth.sock"), **self._camera},
            "mocap": {**common, "command_port": free_udp_port(), "data_port": free_udp_port(),
                      **self._mocap},
            BRIDGE_PART: {**common, "world": str(self.world_path), **(self._bridge or {})},
        }
        return {name: specs[name] for name in self._wanted}

    def start(self, cancel: threading.Event | None = None) -> VehicleSide:
        """Start every part and wait until each is ready; ``cancel`` set meanwhile (a signal)
        stops them all and raises :class:`StartCancelled`."""
        t0 = time.monotonic()
        self.truth = TruthBlock.create()
        self._crashed = False
        try:
            for name, spec in self.specs().items():
                self.parts[name] = self._spawn(name, spec)
            for part in self.parts.values():
                part.info = self._await_ready(part, t0 + self.ready_timeout_s, cancel)
        except BaseException:
            self.stop()
            raise
        self.t_ready_s = time.monotonic() - t0
        return self

    def _spawn(self, name: str, spec: dict[str, Any]) -> Part:
        log_path = self.run_dir / f"{name}.log"
        with open(log_path, "wb") as log_file:
            process = subprocess.Popen(
                [sys.executable, "-m", "sim_harness.sidecar", name, "--spec", json.dumps(spec)],
                stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=log_file,
            )
        return Part(name, process, log_path)

    def _await_ready(self, part: Part, deadline: float, cancel: threading.Event | None) -> dict[str, Any]:
        assert part.process.stdout is not None
        fd = part.process.stdout
        while True:
            if cancel is not None and cancel.is_set():
                raise StartCancelled(f"sim {part.name}: start cancelled")
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise VehicleSideError(f"sim {part.name}: not ready within {self.ready_timeout_s:g} s"
                                       f"{self._log_tail(part)}")
            readable, _, _ = select.select([fd], [], [], min(remaining, 0.5))
            if readable:
                line = fd.readline()
                if not line:
                    code = part.process.wait()
                    raise VehicleSideError(f"sim {part.name}: exited with code {code} before it was "
                                           f"ready{self._log_tail(part)}")
                with contextlib.suppress(json.JSONDecodeError):
                    info = json.loads(line)
                    if isinstance(info, dict) and info.get("ready"):
                        return info

    @staticmethod
    def _log_tail(part: Part, lines: int = 15) -> str:
        try:
            text = part.log_path.read_text(errors="replace").strip().splitlines()[-lines:]
        except OSError:
            return ""
        return ("; its log (" + str(part.log_path) + ") ends:\n  " + "\n  ".join(text)) if text else ""

    def kill(self, name: str, sig: int = signal.SIGKILL) -> None:
        """Send ``sig`` to one part (a fault: the part dies)."""
        part = self.parts[name]
        part.cpu_s = process_cpu_s(part.process.pid)
        part.process.send_signal(sig)

    def cpu_s(self) -> dict[str, float | None]:
        """CPU seconds used so far by each part (the last reading for a stopped one)."""
        out: dict[str, float | None] = {}
        for name, part in self.parts.items():
            now = process_cpu_s(part.process.pid) if part.process.poll() is None else None
            out[name] = now if now is not None else part.cpu_s
        return out

    def stop(self, timeout_s: float = 3.0) -> None:
        for part in self.parts.values():
            if part.process.poll() is None:
                part.cpu_s = process_cpu_s(part.process.pid)
                part.process.terminate()
        deadline = time.monotonic() + timeout_s
        for part in self.parts.values():
            try:
                part.process.wait(max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                part.process.kill()
                part.process.wait()
            if part.process.stdout is not None:
                part.process.stdout.close()
        if self.truth is not None:
            self.truth.close()
            self.truth = None
        if self._own_run_dir:
            shutil.rmtree(self.run_dir, ignore_errors=True)
