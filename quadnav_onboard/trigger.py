"""The mission start condition: how the daemon waits for the operator's go, after preflight.

Three modes (``MissionTriggerConfig.mode``):

``"auto"``
    Go at once. Simulation and dry runs only: :func:`trigger_config_from_mapping` refuses it
    unless the caller says the vehicle is simulated.
``"socket"``
    Go when a local client writes the line ``GO`` to a UNIX stream socket (``socket_path``,
    mode 0660: the ``quadnav`` user and its group only). ``STATUS`` is answered with ``WAITING``.
    The operator runs ``python -m quadnav_onboard.trigger GO`` (or ``socat``) on the companion.
``"offboard_switch"``
    Go when the pilot switches PX4 into OFFBOARD, seen on a mode stream from the vehicle link.
    Only a *transition* counts: if the vehicle is already in OFFBOARD when the wait starts (e.g. the
    daemon was restarted mid-flight), the pilot must leave OFFBOARD and enter it again.

The trigger never arms anything: it only answers "may the mission start now". See
docs/hardware.md ("Mission start") for what the field expects.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os
import socket
import stat
import struct
import sys
import time
from collections.abc import AsyncIterator, Awaitable, Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import pydantic

from quadnav_onboard.config import ConfigError, parse_config
from quadnav_onboard.logs import get_logger

__all__ = [
    "DEFAULT_SOCKET_PATH",
    "Go",
    "MissionTrigger",
    "MissionTriggerConfig",
    "TriggerError",
    "TriggerTimeoutError",
    "send_command",
    "trigger_config_from_mapping",
    "wait_for_go",
]

_log = get_logger(__name__)

DEFAULT_SOCKET_PATH = "/run/quadnav/trigger.sock"
_SOCKET_MODE = 0o660
_MAX_LINE_BYTES = 64


class TriggerError(RuntimeError):
    """The go could not be waited for (socket in use, mode stream ended, bad set-up)."""


class TriggerTimeoutError(TriggerError, TimeoutError):
    """No go arrived within ``timeout_s``."""


@dataclass(frozen=True)
class MissionTriggerConfig:
    """When the mission may start, once preflight has passed."""

    __pydantic_config__ = {"extra": "forbid", "allow_inf_nan": False}  # unknown keys, NaN, ±inf: errors

    mode: Literal["auto", "socket", "offboard_switch"] = "offboard_switch"
    """auto: at once (sim only); socket: a ``GO`` line on ``socket_path``; offboard_switch: the
    pilot switches PX4 to OFFBOARD."""
    socket_path: Annotated[str, pydantic.Field(min_length=2, max_length=107)] = DEFAULT_SOCKET_PATH
    """socket: absolute path of the UNIX socket (created mode 0660, removed after the go)."""
    client_timeout_s: Annotated[float, pydantic.Field(gt=0, le=3600)] = 30.0
    """socket: a client that sends no complete line for this long (s), in (0, 3600], is disconnected."""

    def __post_init__(self) -> None:
        if not self.socket_path.startswith("/"):
            raise ValueError(f"socket_path {self.socket_path!r} must be an absolute path")


@dataclass(frozen=True)
class Go:
    """The operator's go, as recorded in the flight record."""

    mode: str
    """The trigger mode that fired."""
    t_mono_s: float
    """When it fired (monotonic s)."""
    detail: str
    """Who or what gave it: the socket peer's pid/uid, or the mode transition."""


def trigger_config_from_mapping(
    data: Mapping[str, Any] | None, *, source: str, simulated: bool
) -> MissionTriggerConfig:
    """Validate the flight config's ``trigger:`` section; ``None`` means auto in sim, else an error.

    Raises :class:`ConfigError` naming ``source`` and the key when a real vehicle would start
    by itself (``mode: auto``, or no trigger section at all).
    """
    if data is None:
        if simulated:
            return MissionTriggerConfig(mode="auto")
        raise ConfigError(
            f"{source}: key 'trigger': required for a real vehicle "
            "(mode: offboard_switch or socket; see docs/hardware.md)"
        )
    try:
        cfg = parse_config(MissionTriggerConfig, data, source=source)
    except ConfigError as exc:
        raise ConfigError(str(exc).replace(": key '", ": key 'trigger.")) from None
    if cfg.mode == "auto" and not simulated:
        raise ConfigError(
            f"{source}: key 'trigger.mode': bad value 'auto': a real vehicle needs an explicit go "
            "(offboard_switch or socket)"
        )
    return cfg


def _mode_name(mode: object) -> str:
    """'OFFBOARD' from a str, a MAVSDK FlightMode enum, or 'FlightMode.OFFBOARD'."""
    name = mode if isinstance(mode, str) else getattr(mode, "name", str(mode))
    return name.rsplit(".", 1)[-1].strip().upper()


async def _wait_offboard_switch(mode_stream: AsyncIterator[object]) -> Go:
    previous: str | None = None
    async for mode in mode_stream:
        name = _mode_name(mode)
        if name == "OFFBOARD" and previous is not None and previous != "OFFBOARD":
            return Go("offboard_switch", time.monotonic(), f"mode {previous} -> OFFBOARD")
        if name == "OFFBOARD" and previous is None:
            _log.warning("vehicle already in OFFBOARD; waiting for the pilot to leave and re-enter it")
        if name != previous:
            _log.info("flight mode", mode=name)
        previous = name
    raise TriggerError("the flight-mode stream ended before the pilot switched to OFFBOARD")


def _peer(writer: asyncio.StreamWriter) -> str:
    sock = writer.get_extra_info("socket")
    try:
        pid, uid, gid = struct.unpack("3i", sock.getsockopt(socket.SOL_SOCKET, socket.SO_PEERCRED, 12))
    except (OSError, AttributeError):
        return "peer unknown"
    return f"peer pid={pid} uid={uid} gid={gid}"


def _claim_socket_path(path: Path) -> None:
    """Remove a stale socket left by a dead process; refuse a live one or a non-socket file."""
    try:
        st = path.lstat()
    except FileNotFoundError:
        return
    if not stat.S_ISSOCK(st.st_mode):
        raise TriggerError(f"{path}: exists and is not a socket; refusing to replace it")
    probe = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        probe.connect(str(path))
    except (ConnectionRefusedError, FileNotFoundError):
        path.unlink(missing_ok=True)
        return
    finally:
        probe.close()
    raise TriggerError(f"{path}: another process is listening (a second quadnav daemon?)")


async def _wait_socket(cfg: MissionTriggerConfig) -> Go:
    path = Path(cfg.socket_path)
    if not path.parent.is_dir():
        raise TriggerError(f"{path.parent}: trigger socket folder does not exist (RuntimeDirectory=quadnav?)")
    _claim_socket_path(path)
    go: asyncio.Future[Go] = asyncio.get_running_loop().create_future()

    async def handle(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        peer = _peer(writer)
        try:
            while not reader.at_eof():
                line = await asyncio.wait_for(reader.readline(), cfg.client_timeout_s)
                if not line:
                    break
                command = line.decode("utf-8", "replace").strip()
                if command == "GO":
                    if not go.done():
                        go.set_result(Go("socket", time.monotonic(), peer))
                    _log.info("go received", peer=peer)
                    writer.write(b"OK GO\n")
                elif command == "STATUS":
                    writer.write(b"DONE\n" if go.done() else b"WAITING\n")
                else:
                    writer.write(f"ERR unknown command {command[:32]!r}: send GO or STATUS\n".encode())
                await writer.drain()
        except (TimeoutError, asyncio.TimeoutError, ValueError, ConnectionError):
            pass  # slow, oversized or vanished client: just drop it
        finally:
            writer.close()
            with contextlib.suppress(ConnectionError):
                await writer.wait_closed()

    server = await asyncio.start_unix_server(handle, path=str(path), limit=_MAX_LINE_BYTES)
    try:
        os.chmod(path, _SOCKET_MODE)
        _log.info("waiting for GO", socket=str(path))
        return await go
    finally:
        server.close()
        path.unlink(missing_ok=True)


async def wait_for_go(
    cfg: MissionTriggerConfig,
    *,
    mode_stream: AsyncIterator[object] | None = None,
    timeout_s: float | None = None,
    heartbeat: Callable[[], object] | None = None,
    heartbeat_period_s: float = 0.5,
) -> Go:
    """Wait until the mission may start; return who gave the go.

    ``mode_stream`` (offboard_switch only): flight modes from the vehicle link, as names or MAVSDK
    ``FlightMode`` values (e.g. ``system.telemetry.flight_mode()``). ``heartbeat`` is called every
    ``heartbeat_period_s`` while waiting (feed the systemd watchdog, stream hold setpoints).
    Raises :class:`TriggerTimeoutError` after ``timeout_s``, :class:`TriggerError` on a bad set-up.
    """
    if cfg.mode == "auto":
        return Go("auto", time.monotonic(), "auto start (simulation)")
    waiter: Awaitable[Go]
    if cfg.mode == "offboard_switch":
        if mode_stream is None:
            raise TriggerError("trigger mode offboard_switch needs a flight-mode stream (vehicle link)")
        waiter = _wait_offboard_switch(mode_stream)
    else:
        waiter = _wait_socket(cfg)
    task = asyncio.ensure_future(waiter)
    deadline = None if timeout_s is None else time.monotonic() + timeout_s
    try:
        while True:
            wait_s = heartbeat_period_s
            if deadline is not None:
                wait_s = min(wait_s, deadline - time.monotonic())
                if wait_s <= 0:
                    raise TriggerTimeoutError(f"no go ({cfg.mode}) within {timeout_s} s")
            done, _ = await asyncio.wait({task}, timeout=wait_s)
            if done:
                return task.result()
            if heartbeat is not None:
                heartbeat()
    finally:
        if not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task


class MissionTrigger:
    """:func:`wait_for_go` bound to one config."""

    def __init__(self, config: MissionTriggerConfig) -> None:
        self.config = config

    async def wait_for_go(self, **kwargs: Any) -> Go:
        """See :func:`wait_for_go`."""
        return await wait_for_go(self.config, **kwargs)


async def send_command(socket_path: str, command: str = "GO", timeout_s: float = 5.0) -> str:
    """Client side: send one command line to a waiting daemon and return its one-line answer."""
    reader, writer = await asyncio.wait_for(asyncio.open_unix_connection(socket_path), timeout_s)
    try:
        writer.write(command.strip().encode() + b"\n")
        await writer.drain()
        return (await asyncio.wait_for(reader.readline(), timeout_s)).decode().strip()
    finally:
        writer.close()
        with contextlib.suppress(ConnectionError):
            await writer.wait_closed()


def main(argv: list[str] | None = None) -> int:
    """``python -m quadnav_onboard.trigger [GO|STATUS] [--socket PATH]``: the operator's go."""
    p = argparse.ArgumentParser(prog="python -m quadnav_onboard.trigger", description=main.__doc__)
    p.add_argument("command", nargs="?", default="STATUS", choices=["GO", "STATUS"])
    p.add_argument("--socket", default=DEFAULT_SOCKET_PATH, help=f"default {DEFAULT_SOCKET_PATH}")
    args = p.parse_args(argv)
    try:
        answer = asyncio.run(send_command(args.socket, args.command))
    except (OSError, TimeoutError, asyncio.TimeoutError) as exc:
        print(f"{args.socket}: no daemon waiting for a go ({exc})", file=sys.stderr)
        return 1
    print(answer)
    return 0 if not answer.startswith("ERR") else 1


if __name__ == "__main__":
    sys.exit(main())
