"""Mission trigger: the mission starts only on an explicit go (a GO line on the socket, or the pilot)."""

from __future__ import annotations

import asyncio
import os
import socket
import stat
import tempfile
from collections.abc import AsyncIterator, Iterable, Iterator
from pathlib import Path

import pytest
from mavsdk.asyncio.plugins.telemetry.telemetry import FlightMode

from quadnav_onboard.config import ConfigError
from quadnav_onboard.trigger import (
    MissionTrigger,
    MissionTriggerConfig,
    TriggerError,
    TriggerTimeoutError,
    main,
    send_command,
    trigger_config_from_mapping,
    wait_for_go,
)


@pytest.fixture
def sock_path() -> Iterator[Path]:
    """A short socket path (AF_UNIX paths are limited to 107 bytes)."""
    with tempfile.TemporaryDirectory(prefix="qn-", dir="/tmp") as d:
        yield Path(d) / "trigger.sock"


async def _until_listening(path: Path) -> None:
    for _ in range(500):
        if path.exists():
            return
        await asyncio.sleep(0.01)
    raise AssertionError(f"{path} never appeared")


async def test_auto_goes_at_once() -> None:
    """mode auto (simulation) returns immediately without any input."""
    go = await asyncio.wait_for(wait_for_go(MissionTriggerConfig(mode="auto")), 1.0)
    assert go.mode == "auto"


async def test_socket_go_line_starts_the_mission_and_is_answered(sock_path: Path) -> None:
    """A GO line on the 0660 socket fires the trigger, names the peer, and the socket is removed after."""
    cfg = MissionTriggerConfig(mode="socket", socket_path=str(sock_path))
    task = asyncio.create_task(MissionTrigger(cfg).wait_for_go(timeout_s=20.0))
    await _until_listening(sock_path)
    assert stat.S_IMODE(sock_path.stat().st_mode) == 0o660
    assert stat.S_ISSOCK(sock_path.stat().st_mode)
    assert await send_command(str(sock_path), "STATUS") == "WAITING"
    assert not task.done()
    assert await send_command(str(sock_path), "GO") == "OK GO"
    go = await asyncio.wait_for(task, 5.0)
    assert go.mode == "socket"
    assert f"pid={os.getpid()}" in go.detail and f"uid={os.getuid()}" in go.detail
    assert not sock_path.exists()


async def test_socket_ignores_anything_but_go(sock_path: Path) -> None:
    """Unknown commands, lower-case 'go' and over-long lines are refused and do not start the mission."""
    cfg = MissionTriggerConfig(mode="socket", socket_path=str(sock_path))
    task = asyncio.create_task(wait_for_go(cfg, timeout_s=20.0))
    await _until_listening(sock_path)
    assert (await send_command(str(sock_path), "ARM")).startswith("ERR unknown command")
    assert (await send_command(str(sock_path), "go")).startswith("ERR")
    reader, writer = await asyncio.open_unix_connection(str(sock_path))
    writer.write(b"G" * 200 + b"O\n")
    await writer.drain()
    assert await asyncio.wait_for(reader.read(), 5.0) == b""  # dropped without an answer
    writer.close()
    await asyncio.sleep(0.05)
    assert not task.done()
    assert await send_command(str(sock_path), "GO") == "OK GO"
    assert (await asyncio.wait_for(task, 5.0)).mode == "socket"


async def test_socket_times_out_and_feeds_the_heartbeat(sock_path: Path) -> None:
    """Without a go the wait ends with TriggerTimeoutError, calling the heartbeat while it waits."""
    beats: list[int] = []
    cfg = MissionTriggerConfig(mode="socket", socket_path=str(sock_path))
    with pytest.raises(TriggerTimeoutError, match="no go"):
        await wait_for_go(cfg, timeout_s=0.3, heartbeat=lambda: beats.append(1), heartbeat_period_s=0.05)
    assert len(beats) >= 3
    assert not sock_path.exists()


async def test_stale_socket_is_replaced_but_a_live_one_is_refused(sock_path: Path) -> None:
    """A socket file left by a dead daemon is reused; one with a live listener or a plain file is not."""
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(sock_path))
    stale.close()  # file stays, nobody listens
    cfg = MissionTriggerConfig(mode="socket", socket_path=str(sock_path))
    task = asyncio.create_task(wait_for_go(cfg, timeout_s=20.0))
    for _ in range(500):  # until the new listener has replaced the stale file
        try:
            assert await send_command(str(sock_path), "STATUS") == "WAITING"
            break
        except ConnectionRefusedError:
            await asyncio.sleep(0.01)
    else:
        raise AssertionError("the stale socket was never replaced")
    with pytest.raises(TriggerError, match="another process is listening"):
        await wait_for_go(cfg, timeout_s=1.0)
    assert await send_command(str(sock_path), "GO") == "OK GO"
    await asyncio.wait_for(task, 5.0)
    sock_path.write_text("not a socket")
    with pytest.raises(TriggerError, match="not a socket"):
        await wait_for_go(cfg, timeout_s=1.0)


async def _modes(names: Iterable[object], consumed: list[object]) -> AsyncIterator[object]:
    for n in names:
        consumed.append(n)
        yield n
        await asyncio.sleep(0)


async def test_offboard_switch_fires_on_the_pilots_transition() -> None:
    """HOLD -> POSCTL -> OFFBOARD fires on the OFFBOARD update, not before."""
    consumed: list[object] = []
    stream = _modes(["HOLD", "POSCTL", "OFFBOARD", "LAND"], consumed)
    go = await wait_for_go(MissionTriggerConfig(mode="offboard_switch"), mode_stream=stream, timeout_s=5.0)
    assert go.mode == "offboard_switch"
    assert go.detail == "mode POSCTL -> OFFBOARD"
    assert consumed == ["HOLD", "POSCTL", "OFFBOARD"]


async def test_already_in_offboard_at_start_needs_a_fresh_switch() -> None:
    """After a restart mid-flight (vehicle already OFFBOARD) the pilot must leave and re-enter OFFBOARD."""
    consumed: list[object] = []
    modes = [FlightMode.OFFBOARD, FlightMode.OFFBOARD, FlightMode.POSCTL, FlightMode.OFFBOARD]
    go = await wait_for_go(
        MissionTriggerConfig(mode="offboard_switch"), mode_stream=_modes(modes, consumed), timeout_s=5.0
    )
    assert len(consumed) == 4
    assert go.detail == "mode POSCTL -> OFFBOARD"


async def test_offboard_switch_errors() -> None:
    """A stream that ends, a missing stream, or a pilot who never switches: clear errors, no go."""
    cfg = MissionTriggerConfig(mode="offboard_switch")
    with pytest.raises(TriggerError, match="stream ended"):
        await wait_for_go(cfg, mode_stream=_modes(["OFFBOARD", "OFFBOARD"], []), timeout_s=5.0)
    with pytest.raises(TriggerError, match="needs a flight-mode stream"):
        await wait_for_go(cfg, timeout_s=1.0)
    queue: asyncio.Queue[str] = asyncio.Queue(maxsize=4)
    queue.put_nowait("POSCTL")

    async def stalled() -> AsyncIterator[str]:
        while True:
            yield await queue.get()

    with pytest.raises(TriggerTimeoutError):
        await wait_for_go(cfg, mode_stream=stalled(), timeout_s=0.2)


def test_config_refuses_auto_start_on_a_real_vehicle() -> None:
    """No trigger section or mode auto is fine in sim and a ConfigError naming the key on hardware."""
    assert trigger_config_from_mapping(None, source="sim.yaml", simulated=True).mode == "auto"
    with pytest.raises(ConfigError, match=r"flight\.yaml: key 'trigger'"):
        trigger_config_from_mapping(None, source="flight.yaml", simulated=False)
    with pytest.raises(ConfigError, match=r"key 'trigger\.mode': bad value 'auto'"):
        trigger_config_from_mapping({"mode": "auto"}, source="flight.yaml", simulated=False)
    ok = trigger_config_from_mapping({"mode": "socket"}, source="flight.yaml", simulated=False)
    assert ok.mode == "socket" and ok.socket_path == "/run/quadnav/trigger.sock"


def test_config_errors_name_file_key_and_value() -> None:
    """Typos and bad values are reported with the file, the trigger.* key and the value."""
    with pytest.raises(ConfigError, match=r"f\.yaml: key 'trigger\.mdoe': unknown key"):
        trigger_config_from_mapping({"mdoe": "socket"}, source="f.yaml", simulated=False)
    with pytest.raises(ConfigError, match=r"key 'trigger\.mode': bad value 'switch'"):
        trigger_config_from_mapping({"mode": "switch"}, source="f.yaml", simulated=False)
    with pytest.raises(ConfigError, match="must be an absolute path"):
        trigger_config_from_mapping({"socket_path": "run/x.sock"}, source="f.yaml", simulated=False)


def test_cli_without_a_waiting_daemon_fails_cleanly(
    sock_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The operator's command reports 'no daemon waiting' and exits 1 instead of a traceback."""
    assert main(["GO", "--socket", str(sock_path)]) == 1
    assert "no daemon waiting" in capsys.readouterr().err


async def test_cli_sends_go(sock_path: Path) -> None:
    """The operator's command delivers GO to a waiting daemon and exits 0."""
    cfg = MissionTriggerConfig(mode="socket", socket_path=str(sock_path))
    task = asyncio.create_task(wait_for_go(cfg, timeout_s=20.0))
    await _until_listening(sock_path)
    assert await asyncio.to_thread(main, ["GO", "--socket", str(sock_path)]) == 0
    assert (await asyncio.wait_for(task, 5.0)).mode == "socket"
