"""Ports handed to stand-ins and tests: free, distinct, and never the kernel's own pick."""

from __future__ import annotations

import random
import socket
from pathlib import Path

import pytest

from quadnav_onboard import ports
from quadnav_onboard.ports import DEFAULT_EPHEMERAL_LOW, LOWEST_PORT, ephemeral_low
from sim_harness.px4 import free_udp_port


def test_ports_sit_below_the_ephemeral_range_and_bind() -> None:
    high = ephemeral_low()
    for _ in range(20):
        port = free_udp_port()
        assert LOWEST_PORT <= port < high
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.bind(("127.0.0.1", port))


def test_one_process_never_gets_the_same_port_twice_even_if_random_is_seeded() -> None:
    state, ports = random.getstate(), []
    try:
        for _ in range(50):
            random.seed(0)
            ports.append(free_udp_port())
    finally:
        random.setstate(state)
    assert len(set(ports)) == len(ports)


def test_a_port_another_socket_holds_is_skipped(monkeypatch: pytest.MonkeyPatch) -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("127.0.0.1", 0))
        held = holder.getsockname()[1]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            probe.bind(("127.0.0.1", 0))
            spare = probe.getsockname()[1]
        picks = iter([held, spare])
        monkeypatch.setattr(ports, "LOWEST_PORT", 0)
        monkeypatch.setattr(ports, "ephemeral_low", lambda: 65536)
        monkeypatch.setattr(ports._rng, "randrange", lambda lo, hi: next(picks))
        assert free_udp_port() == spare


def test_the_ephemeral_range_is_read_from_the_kernel_file_or_defaults(tmp_path: Path) -> None:
    good = tmp_path / "range"
    good.write_text("40000\t60999\n")
    assert ephemeral_low(good) == 40000
    bad = tmp_path / "bad"
    bad.write_text("not numbers\n")
    assert ephemeral_low(bad) == DEFAULT_EPHEMERAL_LOW
    assert ephemeral_low(tmp_path / "missing") == DEFAULT_EPHEMERAL_LOW
