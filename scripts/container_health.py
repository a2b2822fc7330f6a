#!/usr/bin/env python3
"""The container's health: the daemon's own sd_notify state, as systemd would see it.

In the image there is no systemd to listen to the daemon's notifications (READY=1 once preflight
has passed, WATCHDOG=1 from its main loop, STOPPING=1 when a stop begins:
quadnav_onboard/sdnotify.py). This script takes systemd's place, standard library only:

``container_health.py run [--state FILE] -- quadnav-onboard ARGS...``
    The entry point. Binds a notify socket, starts the daemon with ``NOTIFY_SOCKET`` and
    ``WATCHDOG_USEC`` set (the unit's ``WatchdogSec=10s``), forwards SIGINT/SIGTERM to it, writes
    each notification into the state file (JSON, replaced atomically) and exits with the daemon's
    exit code.
``container_health.py check [--state FILE]``
    The HEALTHCHECK. Exit 0 ("healthy") only when the daemon has sent READY=1, has not sent
    STOPPING=1, and its last notification is younger than the watchdog timeout; otherwise it prints
    why and exits 1. No flight, no simulation, nothing that competes with the planner.

Times are CLOCK_MONOTONIC (shared by the processes of one machine, so ``check`` compares them).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

RUN_DIR = Path(os.environ.get("QUADNAV_RUN_DIR", "/run/quadnav"))
DEFAULT_STATE = RUN_DIR / "health.json"
WATCHDOG_S = 10.0
"""The watchdog timeout handed to the daemon, as systemd/quadnav.service's WatchdogSec=10s."""


def read_state(path: Path) -> dict[str, Any] | None:
    """The state file's content, or None when it is missing or unreadable."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def health(state: dict[str, Any] | None, now_mono_s: float) -> tuple[bool, str]:
    """(healthy, why) for a state written by ``run``, at monotonic time ``now_mono_s``."""
    if state is None:
        return False, "no state file: the daemon was not started through 'container_health.py run'"
    if state.get("exit_code") is not None:
        return False, f"the daemon exited with code {state['exit_code']}"
    if state.get("stopping"):
        return False, f"the daemon is stopping ({state.get('status') or 'no status'})"
    if not state.get("ready"):
        return False, f"not ready yet: preflight has not passed ({state.get('status') or 'no status'})"
    age_s = now_mono_s - float(state.get("t_last_mono_s", float("-inf")))
    timeout_s = float(state.get("watchdog_s", WATCHDOG_S))
    if not age_s <= timeout_s:
        return False, f"no notification for {age_s:.1f} s (watchdog {timeout_s:g} s): the daemon hangs"
    return True, f"ready, last notification {age_s:.1f} s ago ({state.get('status') or 'no status'})"


class StateWriter:
    """Folds sd_notify datagrams into the state and writes it atomically."""

    def __init__(self, path: Path, watchdog_s: float) -> None:
        self.path = path
        self.state: dict[str, Any] = {
            "ready": False,
            "stopping": False,
            "status": None,
            "watchdog_s": watchdog_s,
            "t_start_mono_s": time.monotonic(),
            "t_ready_mono_s": None,
            "t_last_mono_s": None,
            "pid": None,
            "exit_code": None,
        }
        self.lock = threading.Lock()

    def update(self, **fields: Any) -> None:
        with self.lock:
            self.state.update(fields)
            tmp = self.path.with_name(self.path.name + ".tmp")
            tmp.write_text(json.dumps(self.state))
            tmp.replace(self.path)

    def on_datagram(self, data: bytes) -> None:
        now = time.monotonic()
        fields: dict[str, Any] = {"t_last_mono_s": now}
        for line in data.decode("utf-8", errors="replace").splitlines():
            key, _, value = line.partition("=")
            if key == "READY" and value == "1":
                fields.update(ready=True, t_ready_mono_s=now)
            elif key == "STOPPING" and value == "1":
                fields["stopping"] = True
            elif key == "STATUS":
                fields["status"] = value
        self.update(**fields)


def run(command: list[str], state_path: Path, watchdog_s: float) -> int:
    """Start ``command`` under a notify socket next to ``state_path``; its exit code."""
    if not command:
        print("container_health: run: give the daemon's command after --", file=sys.stderr)
        return 2
    sock_path = state_path.with_name("notify.sock")
    with contextlib.suppress(FileNotFoundError):
        sock_path.unlink()
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
    sock.bind(str(sock_path))
    writer = StateWriter(state_path, watchdog_s)
    writer.update()
    env = dict(os.environ, NOTIFY_SOCKET=str(sock_path), WATCHDOG_USEC=str(int(watchdog_s * 1e6)))
    env.pop("WATCHDOG_PID", None)
    try:
        child = subprocess.Popen(command, env=env)
    except OSError as exc:
        print(f"container_health: cannot start {command[0]!r}: {exc}", file=sys.stderr)
        return 127
    writer.update(pid=child.pid)
    for sig in (signal.SIGINT, signal.SIGTERM):  # docker stop: the daemon lands, then exits
        signal.signal(sig, lambda signum, _frame: child.send_signal(signum))

    def listen() -> None:
        while True:
            try:
                data = sock.recv(4096)
            except OSError:
                return
            writer.on_datagram(data)

    threading.Thread(target=listen, name="notify", daemon=True).start()
    code = child.wait()
    writer.update(exit_code=code)
    sock.close()
    return 128 - code if code < 0 else code  # killed by a signal: 128 + its number, as a shell says


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description="the daemon's sd_notify state as the container's health")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="start the daemon under a notify socket (the entry point)")
    r.add_argument("--state", type=Path, default=DEFAULT_STATE, help=f"state file (default {DEFAULT_STATE})")
    r.add_argument(
        "--watchdog-s", type=float, default=WATCHDOG_S, help="watchdog timeout handed to the daemon"
    )
    r.add_argument("command", nargs=argparse.REMAINDER, help="-- quadnav-onboard ARGS...")
    c = sub.add_parser("check", help="exit 0 when the daemon is ready and alive (the HEALTHCHECK)")
    c.add_argument("--state", type=Path, default=DEFAULT_STATE, help=f"state file (default {DEFAULT_STATE})")
    args = p.parse_args(argv)
    if args.cmd == "run":
        command = args.command[1:] if args.command[:1] == ["--"] else args.command
        return run(command, args.state, args.watchdog_s)
    healthy, why = health(read_state(args.state), time.monotonic())
    print(f"{'healthy' if healthy else 'unhealthy'}: {why}")
    return 0 if healthy else 1


if __name__ == "__main__":
    sys.exit(main())
