"""Records open in Foxglove: every channel decodes with its own schema, the transforms form one
tree, log times are UTC and in order per channel, and the 3-D scene and PX4's clock are there."""

from __future__ import annotations

import asyncio
import json
import math
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from mcap.reader import make_reader

from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.record import FlightRecorder, NullRecorder, read_record
from quadnav_onboard.record.decode import DecoderFactory, ProtobufSchema
from quadnav_onboard.record.flight import record_px4_time
from quadnav_onboard.record.schemas import (
    CAMERA_FRAME,
    JSON_SCHEMAS,
    PROTOBUF_SCHEMAS,
    QUADNAV_PROTOBUF,
    TOPICS,
)
from quadnav_onboard.review.cli import main as review_main
from quadnav_onboard.vehicle import MavsdkVehicle

DATA = Path(__file__).parent / "data"

BOX_WORLD = """\
name: short-box
description: a 5 m corridor with one box beside it
path: {waypoints: [[0, 0, 2], [5, 0, 2]], speed_m_s: 1.0}
bounds: {floor_z: 0.0, ceiling_z: 6.0}
obstacles:
  - {type: box, center: [3, 3, 2], size: [1, 1, 2], yaw_deg: 30}
  - {type: cylinder, center: [2, -3, 2], radius: 0.3, height: 3, axis: z}
"""


def _same(a: object, b: object) -> bool:
    """Equal, NaN equal to NaN (a step's fields the daemon does not give are NaN)."""
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a):
        return math.isnan(b)
    return a == b


def _frames_of(topic: str, msg: dict) -> set[str]:
    """Frames a decoded message refers to (besides those it defines)."""
    if "frame_id" in msg:
        return {msg["frame_id"]}
    if topic.startswith(("/scene", "/planner/primitives")):
        return {e["frame_id"] for e in msg["entities"]}
    return set()


@pytest.fixture(scope="module")
def dry_run_record(tmp_path_factory) -> tuple[Path, float, float]:
    """A whole dry run (real daemon, MAVSDK, emulated PX4 and camera processes) and its record,
    with the wall-clock times (s) before and after it."""
    tmp = tmp_path_factory.mktemp("foxglove")
    model, world, rec_dir = tmp / "straight.pt", tmp / "box.yaml", tmp / "records"
    constant_action_checkpoint(str(model), action=4)
    world.write_text(BOX_WORLD)
    t_before = time.time()
    flight = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--world", str(world),
         "--model", str(model), "--record-dir", str(rec_dir), "--log-format", "json"],
        capture_output=True, text=True, timeout=150, check=False,
    )
    t_after = time.time()
    assert flight.returncode == 0, flight.stderr[-2000:]
    (record,) = sorted(rec_dir.glob("*.mcap"))
    return record, t_before, t_after


@pytest.mark.e2e
@pytest.mark.slow
def test_every_channel_of_a_dry_run_decodes_with_its_schema(dry_run_record):
    """Through mcap's reader and the schemas stored in the file: every protobuf message decodes
    with no field its schema lacks, every JSON message has its schema's required keys and no
    others, and every topic of the format carries messages."""
    record, _, _ = dry_run_record
    counts: dict[str, int] = defaultdict(int)
    with open(record, "rb") as f:
        reader = make_reader(f, validate_crcs=True, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            assert schema.name == TOPICS[channel.topic]
            counts[channel.topic] += 1
            if schema.name in PROTOBUF_SCHEMAS or schema.name in QUADNAV_PROTOBUF:
                strict = ProtobufSchema(schema.data).decode(schema.name, message.data, strict=True)
                assert _same(strict, decoded), channel.topic
            else:
                declared = JSON_SCHEMAS[schema.name]
                assert set(declared["required"]) <= set(decoded) <= set(declared["properties"]), channel.topic
    assert set(counts) == set(TOPICS), set(TOPICS) - set(counts)  # PX4's clock included
    assert counts["/planner/primitives"] == counts["/planner/step"] > 0
    assert counts["/tf"] == counts["/odometry"] > 0


@pytest.mark.e2e
@pytest.mark.slow
def test_transforms_form_one_tree_holding_every_frame_used(dry_run_record):
    """world -> body -> camera_depth_optical: each child has one parent, one root, no cycle, and
    every frame a message is drawn in is a frame of the tree; the camera sits at its mount."""
    record, _, _ = dry_run_record
    parents: dict[str, set[str]] = defaultdict(set)
    used: set[str] = set()
    camera = None
    with open(record, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages(log_time_order=False):
            if channel.topic in ("/tf", "/tf_static"):
                parents[msg["child_frame_id"]].add(msg["parent_frame_id"])
                if msg["child_frame_id"] == CAMERA_FRAME:
                    camera = msg
            elif isinstance(msg, dict) and channel.message_encoding == "protobuf":
                used |= _frames_of(channel.topic, msg)
    assert all(len(p) == 1 for p in parents.values()), dict(parents)
    parent = {c: next(iter(p)) for c, p in parents.items()}
    roots = set(parent.values()) - set(parent)
    assert roots == {"world"}
    for frame in parent:  # every frame reaches the root without a cycle
        seen = {frame}
        while frame in parent:
            frame = parent[frame]
            assert frame not in seen
            seen.add(frame)
        assert frame == "world"
    assert used - {"planner_input"} <= set(parent) | roots  # the network's 32x32 input is no camera
    assert parent == {"body": "world", CAMERA_FRAME: "body"}
    q = camera["rotation"]
    # optical z (forward) is body +x: rotating (0, 0, 1) by q gives (1, 0, 0)
    w, x, y, z = q["w"], q["x"], q["y"], q["z"]
    assert [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)] == pytest.approx([1, 0, 0])


@pytest.mark.e2e
@pytest.mark.slow
def test_log_times_are_utc_and_in_order_per_channel(dry_run_record):
    """Every log time lies within the dry run's wall-clock span, and no channel's log times go
    back in the order its messages were written."""
    record, t_before, t_after = dry_run_record
    last: dict[str, int] = {}
    with open(record, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            assert t_before * 1e9 <= message.log_time <= t_after * 1e9, channel.topic
            assert message.log_time >= last.get(channel.topic, 0), channel.topic
            last[channel.topic] = message.log_time
    rec = read_record(record)
    offset_s = rec.unix_minus_mono_ns / 1e9
    assert abs(offset_s - (time.time() - time.monotonic())) < 1.0  # the same clocks, read now
    assert rec.steps and all(0 < s["t_mono_s"] < time.monotonic() for s in rec.steps)


@pytest.mark.e2e
@pytest.mark.slow
def test_the_3d_scene_holds_the_world_the_mission_and_each_steps_primitives(dry_run_record):
    """The world's box and cylinder, the rough path and the geofence, the camera's calibration,
    and per step every primitive (the chosen one apart) from the commanded start."""
    record, _, _ = dry_run_record
    latest: dict[str, list[dict]] = defaultdict(list)
    with open(record, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, _, msg in reader.iter_decoded_messages():
            latest[channel.topic].append(msg)
    (world,) = [e for m in latest["/scene/world"] for e in m["entities"]]
    assert len(world["cylinders"]) == 1 and len(world["cubes"]) == 1 + 2  # the box, floor and ceiling
    box = world["cubes"][0]
    assert box["pose"]["position"] == {"x": 3.0, "y": 3.0, "z": 2.0}
    assert 2 * math.degrees(math.atan2(box["pose"]["orientation"]["z"], box["pose"]["orientation"]["w"])) \
        == pytest.approx(30.0)
    mission = {e["id"]: e for m in latest["/scene/mission"] for e in m["entities"]}
    assert set(mission) == {"rough_path", "geofence"} and len(mission["geofence"]["lines"][0]["points"]) == 24
    (cal,) = latest["/camera/depth/calibration"]
    assert cal["frame_id"] == CAMERA_FRAME and (cal["width"], cal["height"]) == (424, 240)
    assert cal["K"][0] == pytest.approx(212 / math.tan(math.radians(87 / 2)))
    steps = read_record(record).steps
    assert len(latest["/planner/primitives"]) == len(steps)
    for msg in latest["/planner/primitives"]:
        (entity,) = msg["entities"]
        lines = entity["lines"]
        # in action order; the chosen one (action 4, the checkpoint's only choice) drawn thick
        assert len(lines) == 18 and [i for i, ln in enumerate(lines) if ln["thickness"] > 1.5] == [4]
        chosen = lines[4]["points"]
        assert chosen[-1]["x"] > chosen[0]["x"]  # action 4 flies forward


def test_camera_geofence_world_and_px4_clock_come_back(tmp_path):
    """What describes a flight is read back: the world's YAML (for the review's drawings), PX4's
    clock as an offset to add to ULog times, the calibration from the fields of view."""
    path = tmp_path / "f.mcap"
    world = {"name": "w", "path": {"waypoints": [[0, 0, 2], [9, 0, 2]]},
             "obstacles": [{"type": "sphere", "center": [4, 1, 2], "radius": 0.5}]}
    with FlightRecorder(path, metadata={}) as rec:
        rec.camera(10.0, width_px=64, height_px=48, hfov_deg=90.0, vfov_deg=60.0,
                   offset_body_m=(0.1, 0, -0.05))
        rec.geofence(10.0, (-5, -5, 0), (20, 5, 8))
        rec.world(10.0, world)
        rec.px4_time(11.0, 123_000_000, 0)
        rec.close("operator_stop", {}, t_mono_s=12.0)
    r = read_record(path)
    (px4,) = r.px4_time
    utc_us_at_arrival = round((11.0 * 1e9 + r.unix_minus_mono_ns) / 1e3)
    assert px4["px4_boot_us"] == 123_000_000 and px4["px4_unix_us"] is None
    assert px4["unix_minus_px4_boot_us"] == pytest.approx(utc_us_at_arrival - 123_000_000, abs=1)
    assert "sphere" in r.info["world_yaml"]
    with open(path, "rb") as f:
        msgs = {c.topic: m for _, c, _, m in make_reader(f, decoder_factories=[DecoderFactory()])
                .iter_decoded_messages()}
    assert msgs["/camera/depth/calibration"]["K"][0] == pytest.approx(32.0)  # 32 px / tan(45 deg)
    assert msgs["/tf_static"]["translation"] == pytest.approx({"x": 0.1, "y": 0.0, "z": -0.05})
    assert msgs["/scene/world"]["entities"][0]["spheres"][0]["size"]["x"] == 1.0


def test_a_record_of_the_json_format_is_still_read_and_reviewed(capsys):
    """A record written by the previous format (JSON, monotonic log times) reads to the same kind of
    record and reviews to its row."""
    rec = read_record(DATA / "flight-format1.mcap")
    assert rec.format_version == 1 and rec.complete
    assert [s["step"] for s in rec.steps] == list(range(5)) and rec.stop["stop_reason"] == "crash"
    assert rec.steps[0]["t_mono_s"] == 1000.0 and [s for _, s, _ in rec.network_inputs] == list(range(5))
    assert rec.events[0]["kind"] == "mission_start" and len(rec.odom_t_s) > 0
    assert review_main([str(DATA / "flight-format1.mcap"), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    assert row["stop_reason"] == "crash" and row["steps"] == 5


def test_nan_poses_are_refused_but_nan_q_values_are_kept_as_null(tmp_path):
    """A non-finite pose would break the 3-D panel's tree and is dropped as invalid; a NaN Q-value
    (an evaluator that kept none) is written as null and read back as NaN."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={}) as rec:
        rec.odometry(1.0, [np.inf, 0, 0], [1, 0, 0, 0])
        rec.step(1.0, step=0, action=0, q_values=np.full(18, np.nan), rel_pos_body_m=[0, 0, 0],
                 moving_setpoint_world_m=[0, 0, 2], pos_world_m=[0, 0, 2], reward=0.0, reward_terms={},
                 progress_m=0.0, deviation_m=0.0, latency_ms=float("nan"))
        rec.close("operator_stop", {}, t_mono_s=2.0)
        assert rec.drop_counts["invalid"] == 1
    r = read_record(path)
    assert len(r.odom_t_s) == 0 and np.isnan(r.step_array("q_values")).all()


class _Direct:
    """MAVSDK's mavlink_direct plugin as far as the SYSTEM_TIME watch uses it."""

    def __init__(self, messages: list[dict]) -> None:
        self.messages = messages
        self.asked: list[str] = []

    async def subscribe_message(self, name: str):
        self.asked.append(name)
        for fields in self.messages:
            yield SimpleNamespace(fields_json=json.dumps(fields))


def test_px4s_system_time_goes_from_the_link_into_the_record(tmp_path):
    """The vehicle link keeps the newest SYSTEM_TIME (boot time in us, PX4's UTC) with its arrival
    time, skips a garbled one, and the recorder writes it as PX4's offset; no report, no message."""
    vehicle = MavsdkVehicle("udpin://0.0.0.0:14999")
    vehicle._direct = _Direct([
        {"time_unix_usec": 0, "time_boot_ms": 1000},
        {"time_boot_ms": "garbled"},
        {"time_unix_usec": 1_796_000_000_000_000, "time_boot_ms": 2500},
    ])
    assert not record_px4_time(NullRecorder(), vehicle.state)
    before = time.monotonic()
    asyncio.run(vehicle._watch_system_time())
    assert vehicle._direct.asked == ["SYSTEM_TIME"]
    t_arrival, boot_us, unix_us = vehicle.state.px4_time
    assert boot_us == 2_500_000 and unix_us == 1_796_000_000_000_000
    assert before <= t_arrival <= time.monotonic()
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={}) as rec:
        assert record_px4_time(rec, vehicle.state)
        rec.close("operator_stop", {})
    (px4,) = read_record(path).px4_time
    assert px4["px4_boot_us"] == 2_500_000 and px4["px4_unix_us"] == 1_796_000_000_000_000


@pytest.mark.e2e
@pytest.mark.slow
def test_a_dry_runs_record_holds_px4s_clock_from_the_emulated_px4(dry_run_record):
    """The emulated PX4 streams SYSTEM_TIME as PX4 does: the dry run's record carries PX4's time
    since boot and its UTC (the host's, as on SITL), taken during the flight."""
    record, t_before, t_after = dry_run_record
    rec = read_record(record, load_depth=False)
    assert rec.px4_time, "no PX4 clock in the record"
    px4 = rec.px4_time[-1]
    assert px4["px4_boot_us"] > 0
    assert t_before * 1e6 <= px4["px4_unix_us"] <= t_after * 1e6
