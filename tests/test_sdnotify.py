"""sd_notify: READY/WATCHDOG reach a (fake) NOTIFY_SOCKET, and a hung main loop stops the pings."""

from __future__ import annotations

import asyncio
import itertools
import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from quadnav_onboard.sdnotify import SdNotifier, WatchdogFeeder


class FakeSystemd:
    """A NOTIFY_SOCKET listener: records (t_mono_s, message) from a reader thread."""

    def __init__(self, address: str) -> None:
        self.address = address
        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
        self.sock.bind("\0" + address[1:] if address.startswith("@") else address)
        self.sock.settimeout(0.05)
        self.messages: list[tuple[float, str]] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                data = self.sock.recv(4096)
            except TimeoutError:
                continue
            with self._lock:
                self.messages.append((time.monotonic(), data.decode()))

    def wait_for(self, text: str, timeout_s: float = 5.0) -> None:
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if any(text in m for _, m in self.snapshot()):
                return
            time.sleep(0.005)
        raise AssertionError(f"{text!r} never arrived; got {self.snapshot()}")

    def snapshot(self) -> list[tuple[float, str]]:
        with self._lock:
            return list(self.messages)

    def close(self) -> None:
        self._stop.set()
        self._thread.join()
        self.sock.close()


@pytest.fixture(params=["path", "abstract"])
def fake_systemd(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[FakeSystemd]:
    abstract = f"@quadnav-test-{uuid.uuid4().hex}"
    address = str(tmp_path / "notify.sock") if request.param == "path" else abstract
    fake = FakeSystemd(address)
    yield fake
    fake.close()


def test_ready_watchdog_status_stopping_arrive_as_datagrams(fake_systemd: FakeSystemd) -> None:
    """Each call sends one datagram with the sd_notify keys, to a path or an abstract '@' socket."""
    n = SdNotifier.from_env({"NOTIFY_SOCKET": fake_systemd.address})
    assert n.enabled
    assert n.ready(status="preflight passed")
    assert n.watchdog()
    assert n.status("flying\nstep 3")
    assert n.stopping()
    fake_systemd.wait_for("STOPPING=1")
    msgs = [m for _, m in fake_systemd.snapshot()]
    assert msgs == ["READY=1\nSTATUS=preflight passed", "WATCHDOG=1", "STATUS=flying step 3", "STOPPING=1"]
    n.close()


def test_without_notify_socket_every_call_is_a_noop() -> None:
    """Outside systemd nothing is sent and nothing raises; the watchdog is off."""
    n = SdNotifier.from_env({"WATCHDOG_USEC": "3000000"})
    assert not n.enabled
    assert not n.ready() and not n.watchdog() and not n.status("x") and not n.stopping()
    assert n.watchdog_interval_s() is None and n.watchdog_timeout_s() is None


def test_watchdog_interval_is_half_the_timeout_and_only_for_our_pid() -> None:
    """WATCHDOG_USEC=3 s gives a 1.5 s ping interval; a WATCHDOG_PID of another process disables it."""
    env = {"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "3000000", "WATCHDOG_PID": str(os.getpid())}
    mine = SdNotifier.from_env(env)
    assert mine.watchdog_timeout_s() == pytest.approx(3.0)
    assert mine.watchdog_interval_s() == pytest.approx(1.5)
    other = SdNotifier.from_env({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "3000000", "WATCHDOG_PID": "1"})
    assert other.watchdog_interval_s() is None
    garbage = SdNotifier.from_env({"NOTIFY_SOCKET": "@x", "WATCHDOG_USEC": "soon"})
    assert garbage.watchdog_interval_s() is None


def test_send_failure_is_reported_not_raised(tmp_path: Path) -> None:
    """A NOTIFY_SOCKET nobody listens on makes calls return False instead of crashing the daemon."""
    n = SdNotifier(str(tmp_path / "nobody.sock"))
    assert n.ready() is False
    assert n.watchdog() is False


def test_feeder_rate_limits_pings_on_the_monotonic_clock(fake_systemd: FakeSystemd) -> None:
    """A 50 Hz loop kicking every 20 ms pings once per min_period_s of (fake) monotonic time."""
    now = [0.0]
    n = SdNotifier(fake_systemd.address, watchdog_timeout_s=2.0)
    feeder = WatchdogFeeder(n, clock=lambda: now[0])  # default: a quarter of 2 s = 0.5 s
    sent = 0
    for _ in range(100):  # 2 s of fake time
        sent += feeder.kick()
        now[0] += 0.02
    assert sent == 4
    fake_systemd.wait_for("WATCHDOG=1")


async def _main_loop(notifier: SdNotifier, step: asyncio.Event, hang: dict[str, object]) -> None:
    """The daemon's shape: do one step, then feed the watchdog from the loop itself."""
    while True:
        if hang.get("sync_s"):
            time.sleep(float(hang.pop("sync_s")))  # type: ignore[arg-type]  # blocks the event loop
        if hang.get("stuck"):
            await asyncio.Event().wait()  # a hung await: never set, no timeout
        await asyncio.sleep(0.01)
        notifier.watchdog()
        step.set()


async def test_a_stuck_coroutine_stops_the_watchdog_pings(fake_systemd: FakeSystemd) -> None:
    """While the main loop awaits something that never comes, no WATCHDOG=1 is sent at all."""
    n = SdNotifier(fake_systemd.address, watchdog_timeout_s=1.0)
    hang: dict[str, object] = {}
    step = asyncio.Event()
    task = asyncio.create_task(_main_loop(n, step, hang))
    for _ in range(5):
        step.clear()
        await asyncio.wait_for(step.wait(), 5.0)
    hang["stuck"] = True
    await asyncio.sleep(0.05)  # let the loop finish its iteration and reach the stuck await
    await asyncio.to_thread(time.sleep, 0.05)  # let the last in-flight datagram land
    step.clear()
    before = len(fake_systemd.snapshot())
    assert before >= 5
    await asyncio.sleep(0.4)  # 40 loop periods
    assert len(fake_systemd.snapshot()) == before, "pings continued while the main loop was hung"
    assert not step.is_set()
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task


async def test_a_blocked_event_loop_leaves_a_gap_in_the_pings(fake_systemd: FakeSystemd) -> None:
    """A synchronous sleep in the loop blocks all pings for at least its duration."""
    n = SdNotifier(fake_systemd.address, watchdog_timeout_s=1.0)
    hang: dict[str, object] = {}
    step = asyncio.Event()
    task = asyncio.create_task(_main_loop(n, step, hang))
    for _ in range(3):
        step.clear()
        await asyncio.wait_for(step.wait(), 5.0)
    hang["sync_s"] = 0.3
    for _ in range(3):
        step.clear()
        await asyncio.wait_for(step.wait(), 5.0)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    await asyncio.to_thread(time.sleep, 0.05)
    times = [t for t, m in fake_systemd.snapshot() if m == "WATCHDOG=1"]
    gaps = [b - a for a, b in itertools.pairwise(times)]
    assert len(times) >= 6
    assert max(gaps) >= 0.3 - 0.02  # receiver-side timestamps: allow the reader thread's jitter
