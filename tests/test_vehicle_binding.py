"""Binding to one vehicle on a UDP link (quadnav_onboard.vehicle_binding), and the vehicle link's
errors by kind. Raw MAVLink from pymavlink over real loopback UDP; no MAVSDK here."""

from __future__ import annotations

import asyncio
import socket
from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import pytest
from mavsdk.plugins.mocap import MocapError, MocapResult

from quadnav_onboard.ports import ephemeral_low
from quadnav_onboard.vehicle import MavsdkVehicle, VehicleError, VehicleErrorKind
from quadnav_onboard.vehicle_binding import BindingError, LinkGuard, autopilot_frames, guarded_address
from sim_harness.px4 import free_udp_port
from sim_harness.px4.mavlink_io import mavlink2 as m


def packed(msg: m.MAVLink_message, sysid: int, compid: int) -> bytes:
    return msg.pack(m.MAVLink(None, srcSystem=sysid, srcComponent=compid))


def heartbeat(autopilot: int = m.MAV_AUTOPILOT_PX4, kind: int = m.MAV_TYPE_QUADROTOR) -> m.MAVLink_message:
    return m.MAVLink_heartbeat_message(kind, autopilot, 0, 0, m.MAV_STATE_STANDBY, 3)


def test_autopilot_frames_are_an_autopilots_heartbeats_and_its_component_1_traffic() -> None:
    px4 = packed(heartbeat(), 1, 1)
    gcs = packed(heartbeat(m.MAV_AUTOPILOT_INVALID, m.MAV_TYPE_GCS), 255, 190)
    camera_of_2 = packed(heartbeat(m.MAV_AUTOPILOT_INVALID, m.MAV_TYPE_CAMERA), 2, 100)
    odometry_of_3 = packed(m.MAVLink_attitude_quaternion_message(0, 1, 0, 0, 0, 0, 0, 0), 3, 1)
    assert list(autopilot_frames(px4)) == [(1, 1)]
    assert list(autopilot_frames(gcs)) == [] and list(autopilot_frames(camera_of_2)) == []
    assert list(autopilot_frames(odometry_of_3)) == [(3, 1)]
    assert list(autopilot_frames(gcs + px4 + odometry_of_3)) == [(1, 1), (3, 1)]  # several per datagram


def test_autopilot_frames_stop_at_garbage_and_truncated_frames() -> None:
    px4 = packed(heartbeat(), 1, 1)
    assert list(autopilot_frames(b"\x00garbage" + px4)) == []
    assert list(autopilot_frames(px4[:-3])) == []
    assert list(autopilot_frames(b"")) == []


@pytest.mark.parametrize(
    ("url", "address"),
    [
        ("udpin://0.0.0.0:14540", ("0.0.0.0", 14540)),
        ("udpin://127.0.0.1:14550", ("127.0.0.1", 14550)),
        ("udp://:14540", ("0.0.0.0", 14540)),
        ("udpout://10.0.0.2:14540", None),
        ("serial:///dev/ttyACM0:921600", None),
        ("tcpout://127.0.0.1:5760", None),
    ],
)
def test_the_guard_owns_udpin_links_only(url: str, address: tuple[str, int] | None) -> None:
    assert guarded_address(url) == address


@contextmanager
def senders(n: int) -> Iterator[list[socket.socket]]:
    socks = [socket.socket(socket.AF_INET, socket.SOCK_DGRAM) for _ in range(n)]
    try:
        for s in socks:
            s.bind(("127.0.0.1", 0))
            s.setblocking(False)
        yield socks
    finally:
        for s in socks:
            s.close()


async def speak(socks: list[socket.socket], port: int, sysids: list[int], until: asyncio.Event) -> None:
    """Each socket sends its autopilot's heartbeat at 20 Hz to ``port`` until ``until`` is set."""
    while not until.is_set():
        for s, sysid in zip(socks, sysids, strict=True):
            s.sendto(packed(heartbeat(), sysid, 1), ("127.0.0.1", port))
        await asyncio.sleep(0.05)


async def test_one_autopilot_is_bound_by_system_component_and_the_address_it_sent_from() -> None:
    port = free_udp_port()
    guard = LinkGuard(f"udpin://127.0.0.1:{port}", listen_s=0.3)
    done = asyncio.Event()
    with senders(1) as (a,):
        task = asyncio.ensure_future(speak([a], port, [1], done))
        try:
            b = await guard.bind(timeout_s=5.0)
            assert (b.system_id, b.component_id, b.address) == (1, 1, a.getsockname())
            assert guard.mavsdk_url.startswith("udpin://127.0.0.1:")
            # MAVSDK's port is one no port-0 socket can be handed while MAVSDK starts
            assert int(guard.mavsdk_url.rsplit(":", 1)[1]) < ephemeral_low()
        finally:
            done.set()
            await task
            guard.close()


@pytest.mark.parametrize("sysids", [[1, 1], [1, 2]], ids=["same-system-id", "two-system-ids"])
async def test_two_autopilots_on_the_link_are_refused_and_both_named(sysids: list[int]) -> None:
    port = free_udp_port()
    guard = LinkGuard(f"udpin://127.0.0.1:{port}", listen_s=0.3)
    done = asyncio.Event()
    with senders(2) as socks:
        task = asyncio.ensure_future(speak(socks, port, sysids, done))
        try:
            with pytest.raises(BindingError) as err:
                await guard.bind(timeout_s=5.0)
            assert {c.address for c in err.value.candidates} == {s.getsockname() for s in socks}
        finally:
            done.set()
            await task
            guard.close()


async def test_after_binding_only_the_bound_address_is_relayed_and_a_new_source_is_flagged() -> None:
    port = free_udp_port()
    guard = LinkGuard(f"udpin://127.0.0.1:{port}", listen_s=0.2)
    done = asyncio.Event()
    with senders(3) as (bound, impostor, other), socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as mavsdk:
        task = asyncio.ensure_future(speak([bound], port, [1], done))
        try:
            await guard.bind(timeout_s=5.0)
            host, mport = guard.mavsdk_url.removeprefix("udpin://").split(":")
            mavsdk.bind((host, int(mport)))
            mavsdk.setblocking(False)
            loop = asyncio.get_running_loop()
            async with asyncio.timeout(5.0):
                _data, relay = await loop.sock_recvfrom(mavsdk, 65535)  # the vehicle's traffic reaches MAVSDK
                mavsdk.sendto(b"from mavsdk", relay)
                while (got := (await loop.sock_recvfrom(bound, 65535))[0]) != b"from mavsdk":
                    pass  # ... and MAVSDK's reaches the bound vehicle
            assert guard.source_changed is None and not guard.foreign
            other.sendto(packed(heartbeat(), 2, 1), ("127.0.0.1", port))
            impostor.sendto(packed(heartbeat(), 1, 1), ("127.0.0.1", port))
            for _ in range(100):
                if guard.source_changed is not None:
                    break
                await asyncio.sleep(0.01)
            assert guard.source_changed is not None
            assert guard.source_changed.heard.address == impostor.getsockname()
            assert {c.address for c in guard.foreign} == {other.getsockname()}
            assert got == b"from mavsdk"
        finally:
            done.set()
            await task
            guard.close()


class _FailingMocap:
    async def set_vision_position_estimate(self, msg: object) -> None:
        raise MocapError(MocapResult.CONNECTION_ERROR, "set_vision_position_estimate()")


async def test_a_failed_vision_forward_is_a_vehicle_error_of_kind_not_sent() -> None:
    v = MavsdkVehicle("udpin://127.0.0.1:1")
    v._mocap = _FailingMocap()  # type: ignore[assignment]
    with pytest.raises(VehicleError) as err:
        await v.send_vision_position(np.zeros(3), np.array([1.0, 0, 0, 0]), 1.0)
    assert err.value.kind is VehicleErrorKind.NOT_SENT


async def test_a_vision_forward_before_connecting_is_not_connected() -> None:
    v = MavsdkVehicle("udpin://127.0.0.1:1")
    with pytest.raises(VehicleError) as err:
        await v.send_vision_position(np.zeros(3), np.array([1.0, 0, 0, 0]), 1.0)
    assert err.value.kind is VehicleErrorKind.NOT_CONNECTED


@pytest.mark.e2e
async def test_on_a_link_not_owned_two_system_ids_seen_by_mavsdk_are_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Serial and TCP links are MAVSDK's: its list of systems still tells two system IDs apart."""
    import quadnav_onboard.vehicle as vehicle_module
    from sim_harness.px4 import EmulatorConfig, Px4Emulator

    monkeypatch.setattr(vehicle_module, "guarded_address", lambda url: None)
    port = free_udp_port()
    one, two = EmulatorConfig(heartbeat_hz=10.0), EmulatorConfig(heartbeat_hz=10.0, system_id=2)
    with Px4Emulator(None, one, api_port=port), Px4Emulator(None, two, api_port=port):
        v = MavsdkVehicle(f"udpin://127.0.0.1:{port}", connect_timeout_s=10.0, bind_listen_s=1.0)
        try:
            with pytest.raises(VehicleError) as err:
                await v.connect()
            assert err.value.kind is VehicleErrorKind.BINDING
            assert v.state.binding is None
        finally:
            await v.close()
