"""The record's hand-written protobuf: the step message is the core's StepRecord, field for field;
the primitives' scene is the message the SDK would encode; MCAP messages are appended byte for
byte as the mcap library appends them."""

from __future__ import annotations

import dataclasses
import io
import math

import numpy as np
import pytest
from foxglove.messages import (
    LinePrimitive,
    LinePrimitiveLineType,
    Point3,
    SceneEntity,
    SceneUpdate,
    SpherePrimitive,
)
from mcap.writer import CompressionType, Writer

from quadnav_onboard import step
from quadnav_onboard.primitives import PrimitiveSet
from quadnav_onboard.record import FlightRecorder, read_record, scene, step_msg
from quadnav_onboard.record.decode import ProtobufSchema
from quadnav_onboard.record.sink import _fast_add

PRIMS = PrimitiveSet()


def _record(rng: np.random.Generator, k: int, shield: bool = True) -> step.StepRecord:
    one = lambda v, dtype=np.float64: np.array([v], dtype=dtype)  # noqa: E731
    return step.StepRecord(
        step=one(k, np.int64), action=one(int(rng.integers(18)), np.int64), q_values=rng.normal(size=(1, 18)),
        rel_pos_body_m=rng.normal(size=(1, 3)), moving_setpoint_world_m=rng.normal(size=(1, 3)),
        pos_world_m=rng.normal(size=(1, 3)), yaw_rad=one(rng.uniform(-3, 3)),
        end_pos_world_m=rng.normal(size=(1, 3)),
        d_prev_m=one(rng.uniform()), d_now_m=one(rng.uniform()), progress_m=one(rng.uniform(0, 20)),
        deviation_m=one(rng.uniform()), deviated=one(bool(rng.integers(2)), np.bool_),
        collided=one(bool(rng.integers(2)), np.bool_), reward=one(rng.normal()),
        outcome=one(int(rng.integers(5)), np.int8),
        shield_allowed=rng.integers(2, size=(1, 18)).astype(bool) if shield else None,
        shield_clearance_m=rng.uniform(0, 3, size=(1, 18)) if shield else None,
    )


def test_the_step_schema_is_the_step_records_fields_in_order():
    """quadnav.Step declares t_mono_s, then every StepRecord field under its own name, then
    latency_ms; the single-valued ones are exactly those the record holds one value of."""
    names = [f.name for f in step_msg.FIELDS]
    assert names == ["t_mono_s", *(f.name for f in dataclasses.fields(step.StepRecord)), "latency_ms"]
    assert set(names) >= step_msg.ROW_SCALARS
    schema = ProtobufSchema(step_msg.descriptor_set())
    declared = {f.name: f for f in schema.messages["quadnav.Step"].values()}
    assert set(declared) == set(names)
    rec = _record(np.random.default_rng(0), 3)
    for f in dataclasses.fields(step.StepRecord):
        assert declared[f.name].repeated == (getattr(rec, f.name).ndim == 2), f.name


def test_a_step_record_comes_back_from_the_file_value_for_value(tmp_path):
    """Steps recorded with step_record read back, through the record's own schema, as the same
    StepRecord (every field, N = steps), with their decision times and latencies."""
    rng = np.random.default_rng(1)
    recs = [_record(rng, k) for k in range(6)]
    path = tmp_path / "r.mcap"
    with FlightRecorder(path, metadata={}) as rec:
        for k, r in enumerate(recs):
            rec.step_record(10.0 + k, r, latency_ms=2.0 + k)
        rec.close("goal_reached", {}, t_mono_s=20.0)
    back = read_record(path)
    assert back.complete and back.format_version == 3
    got = back.step_record()
    for f in dataclasses.fields(step.StepRecord):
        want = np.concatenate([getattr(r, f.name) for r in recs])
        np.testing.assert_array_equal(getattr(got, f.name), want, err_msg=f.name)
        assert getattr(got, f.name).dtype == want.dtype, f.name
    np.testing.assert_allclose(back.step_t_s, 10.0 + np.arange(6))
    np.testing.assert_allclose(back.step_array("latency_ms"), 2.0 + np.arange(6))


def test_a_step_without_the_filter_reads_back_without_its_verdicts(tmp_path):
    """A record whose filter was off has None verdicts, in the messages and in the StepRecord."""
    path = tmp_path / "r.mcap"
    with FlightRecorder(path, metadata={}) as rec:
        rec.step_record(1.0, _record(np.random.default_rng(2), 0, shield=False))
        rec.close("goal_reached", {}, t_mono_s=2.0)
    back = read_record(path)
    assert back.steps[0]["shield_allowed"] is None and back.steps[0]["shield_clearance_m"] is None
    assert back.step_record().shield_allowed is None and math.isnan(back.steps[0]["latency_ms"])


def test_a_record_of_several_vehicles_is_refused_and_counted(tmp_path):
    """step_record takes one vehicle's step: an N = 2 record is counted invalid, never raised."""
    rng = np.random.default_rng(3)
    a, b = _record(rng, 0), _record(rng, 1)
    both = step.StepRecord(**{
        f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in dataclasses.fields(a)
    })
    with FlightRecorder(tmp_path / "r.mcap", metadata={}) as rec:
        rec.step_record(1.0, both)
        rec.close("goal_reached", {})
    assert rec.drop_counts["invalid"] == 1


def test_the_step_bytes_parse_with_googles_protobuf_runtime():
    """The generated FileDescriptorSet loads into protobuf's own descriptor pool, and the step's
    bytes parse there to the record's values (what Foxglove's protobuf decoding relies on)."""
    descriptor_pb2 = pytest.importorskip("google.protobuf.descriptor_pb2")
    from google.protobuf import descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(step_msg.descriptor_set()).file:
        pool.Add(f)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("quadnav.Step"))
    r = _record(np.random.default_rng(4), 9)
    m = cls.FromString(step_msg.encode_record(5.5, r, 1.25))
    assert (m.t_mono_s, m.step, m.action, m.outcome, m.latency_ms) == (
        5.5, 9, int(r.action[0]), int(r.outcome[0]), 1.25
    )
    assert list(m.q_values) == r.q_values[0].tolist()
    assert list(m.shield_allowed) == r.shield_allowed[0].tolist() and m.collided == bool(r.collided[0])


def test_the_fast_step_encoding_is_the_generic_one():
    """encode_record (straight from the arrays) writes the bytes encode writes from the row."""
    rng = np.random.default_rng(5)
    for shield in (True, False):
        r = _record(rng, 4, shield)
        assert step_msg.encode_record(3.0, r, 7.0) == step_msg.encode(step_msg.row_of_record(3.0, r, 7.0))


def _sdk_primitives(t_ns, curves, chosen, allowed, setpoint):
    lines = [
        LinePrimitive(
            type=LinePrimitiveLineType.LineStrip, thickness=4.0 if i == chosen else 1.5, scale_invariant=True,
            points=[Point3(x=x, y=y, z=z) for x, y, z in curves[i].tolist()],
            color=scene._CHOSEN if i == chosen else scene._ALLOWED if allowed[i] else scene._VETOED,
        )
        for i in range(len(curves))
    ]
    size = scene._v3((0.3, 0.3, 0.3))
    sphere = SpherePrimitive(pose=scene._pose(setpoint), size=size, color=scene._SETPOINT)
    entity = SceneEntity(timestamp=scene._stamp(t_ns), frame_id="world", id="primitives", lines=lines,
                         spheres=[sphere])
    return SceneUpdate(entities=[entity]).encode()


def test_the_primitives_scene_is_the_message_the_sdk_encodes():
    """For random starts, velocities, headings, choices and verdicts, the scene's bytes decode
    (by the SDK's schema, strictly) to what the SDK encodes from the same curves; the curves are
    the rollout the flight commands (step.primitive_targets)."""
    schema = ProtobufSchema(SceneUpdate.get_schema().data)
    rng = np.random.default_rng(6)
    u = np.linspace(0.0, 1.0, scene.CURVE_POINTS)[:, None]
    for _ in range(20):
        start, vel, yaw = rng.normal(size=3) * 5, rng.normal(size=3), float(rng.uniform(-3.2, 3.2))
        chosen, allowed = int(rng.integers(18)), rng.integers(2, size=18).astype(bool)
        setpoint, t_ns = rng.normal(size=3), int(rng.integers(1, 4 * 10**18))  # UTC ns before 2096
        ours = scene.encode_primitives(t_ns, PRIMS, start_world_m=start, start_vel_world_m_s=vel, yaw_rad=yaw,
                                       action=chosen, allowed=allowed, moving_setpoint_world_m=setpoint)
        curves = scene.primitive_curves_world_m(PRIMS, start, vel, yaw)
        flown = np.stack([
            step.primitive_targets(PRIMS, [a], start[None], vel[None], [yaw], u)[0][:, 0] for a in range(18)
        ])
        np.testing.assert_allclose(curves, flown, atol=1e-12)
        sdk = _sdk_primitives(t_ns, curves, chosen, allowed, setpoint)
        assert schema.decode("foxglove.SceneUpdate", ours, strict=True) == schema.decode(
            "foxglove.SceneUpdate", sdk
        )


def test_a_verdict_or_choice_that_does_not_fit_the_set_is_an_error():
    """A verdict of the wrong length or an action outside the set raises ValueError (counted as
    an invalid item by the sink)."""
    kw = dict(
        start_world_m=[0, 0, 2], start_vel_world_m_s=[1, 0, 0], yaw_rad=0.0, moving_setpoint_world_m=[0, 0, 2]
    )
    with pytest.raises(ValueError, match="verdict"):
        scene.encode_primitives(1, PRIMS, action=0, allowed=np.ones(17, bool), **kw)
    with pytest.raises(ValueError, match="action"):
        scene.encode_primitives(1, PRIMS, action=18, allowed=None, **kw)


def test_messages_are_appended_as_the_mcap_library_appends_them():
    """The sink's message path writes the same file, byte for byte, as Writer.add_message, over
    several chunks, two channels and out-of-order log times."""
    rng = np.random.default_rng(7)
    times = rng.integers(1, 10**12, 300)
    msgs = [
        (1 + i % 2, int(t), rng.bytes(int(rng.integers(1, 9000))), int(t) + 5, i) for i, t in enumerate(times)
    ]
    files = []
    for fast in (False, True):
        f = io.BytesIO()
        w = Writer(f, chunk_size=64 * 1024, compression=CompressionType.ZSTD, enable_crcs=True)
        w.start(profile="", library="test")
        sid = w.register_schema("s", "jsonschema", b"{}")
        for topic in ("/a", "/b"):
            w.register_channel(topic, "json", sid)
        add = _fast_add(w)
        assert add is not None
        for ch, log_time, data, pub, seq in msgs:
            if fast:
                add(ch, log_time, data, pub, seq)
            else:
                w.add_message(ch, log_time=log_time, data=data, publish_time=pub, sequence=seq)
        w.finish()
        files.append(f.getvalue())
    assert files[0] == files[1]
