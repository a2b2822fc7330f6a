"""Damaged records: whatever the damage, the reader returns a record or raises RecordError — nothing else."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader

from quadnav_onboard.record import FlightRecorder, RecordError, read_record
from quadnav_onboard.record.decode import ProtobufSchema
from quadnav_onboard.record.schemas import JSON_SCHEMAS, PROTOBUF_SCHEMAS, QUADNAV_PROTOBUF, TOPICS

_DATA: dict[str, bytes] = {}


def _record_bytes(tmp_path_factory) -> bytes:
    if "rec" not in _DATA:
        path = tmp_path_factory.mktemp("fuzz") / "r.mcap"
        with FlightRecorder(
            path, metadata={"world": "w", "config_yaml": "a: 1\n"}, chunk_size=1024, depth_decimation=1
        ) as rec:
            rec.rough_path(1.0, [[0, 0, 2], [5, 0, 2]])
            for k in range(20):
                rec.depth(1.0 + k, np.full((8, 8), k, np.uint16))
                rec.network_input(1.0 + k, k, np.zeros((32, 32), np.float32))
                rec.odometry(1.0 + k, [k, 0, 2], [1, 0, 0, 0], [1, 0, 0])
                rec.setpoint(1.0 + k, [k, 0, 2], [1, 0, 0], 0.0)
                rec.step(
                    1.0 + k,
                    step=k,
                    action=3,
                    q_values=np.arange(18.0),
                    rel_pos_body_m=[1, 0, 0],
                    moving_setpoint_world_m=[k, 0, 2],
                    pos_world_m=[k, 0, 2],
                    reward=0.1,
                    reward_terms={},
                    progress_m=float(k),
                    deviation_m=0.0,
                    latency_ms=3.0,
                )
                rec.vehicle(1.0 + k, True, "OFFBOARD", {})
            rec.event(3.0, "failsafe", "x")
            rec.close("goal_reached", {"steps": 20}, t_mono_s=30.0)
        _DATA["rec"] = path.read_bytes()
    return _DATA["rec"]


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    flips=st.lists(st.tuples(st.floats(0, 1, exclude_max=True), st.integers(0, 255)), min_size=1, max_size=4),
    cut=st.one_of(st.none(), st.floats(0, 1)),
)
def test_damaged_records_never_crash_the_reader(tmp_path_factory, tmp_path, flips, cut):
    """Random byte damage and truncation: a prefix of the decisions comes back, or a RecordError."""
    data = bytearray(_record_bytes(tmp_path_factory))
    for pos, val in flips:
        data[int(pos * len(data))] = val
    if cut is not None:
        data = data[: int(cut * len(data))]
    p = tmp_path / "d.mcap"
    p.write_bytes(bytes(data))
    try:
        rec = read_record(p)
    except RecordError:
        return
    steps = [s["step"] for s in rec.steps]
    assert len(steps) <= 20


def test_every_message_fits_its_foxglove_or_quadnav_schema(tmp_path_factory, tmp_path):
    """Each protobuf message decodes by its own schema with no undeclared field; each JSON message
    has its schema's required keys and no others; raw images are consistent in size."""
    p = tmp_path / "r.mcap"
    p.write_bytes(_record_bytes(tmp_path_factory))
    seen = set()
    with open(p, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            assert schema.name == TOPICS[channel.topic]
            seen.add(channel.topic)
            if schema.name in PROTOBUF_SCHEMAS or schema.name in QUADNAV_PROTOBUF:
                assert schema.encoding == "protobuf" and channel.message_encoding == "protobuf"
                msg = ProtobufSchema(schema.data).decode(schema.name, message.data, strict=True)
            else:
                assert schema.encoding == "jsonschema" and channel.message_encoding == "json"
                msg = json.loads(message.data)
                declared = JSON_SCHEMAS[schema.name]
                assert set(declared["required"]) <= set(msg) <= set(declared["properties"]), channel.topic
            if schema.name == "foxglove.RawImage":
                item = {"16UC1": 2, "32FC1": 4}[msg["encoding"]]
                assert msg["step"] == msg["width"] * item
                assert len(msg["data"]) == msg["height"] * msg["step"]
    assert {"/camera/depth", "/planner/input", "/odometry", "/tf", "/planner/step", "/events"} <= seen
