"""The flight recorder: what goes in comes back out, it never blocks, and it sheds depth first."""

from __future__ import annotations

import math
import threading

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from quadnav_onboard.record import FlightRecorder, NullRecorder, RecorderError, RecordError, read_record
from quadnav_onboard.record.recorder import RecordExistsError, record_name
from quadnav_onboard.record.schemas import JSON_SCHEMAS, PROTOBUF_SCHEMAS, QUADNAV_PROTOBUF, TOPICS


def _fill(rec: FlightRecorder, n: int = 10, t0: float = 50.0) -> None:
    rec.rough_path(t0, [[0, 0, 2], [20, 0, 2]])
    for k in range(n):
        t = t0 + k
        rec.depth(t, np.full((24, 32), 1000 + k, np.uint16))
        rec.network_input(t, k, np.full((32, 32), k / 100, np.float32))
        rec.odometry(t, [k, 0.5, 2.0], [1.0, 0.0, 0.0, 0.0], [1.0, 0.0, 0.0])
        rec.setpoint(t, [k + 1, 0.0, 2.0], [1.0, 0.0, 0.0], 0.1 * k)
        rec.step(
            t,
            step=k,
            action=k % 18,
            q_values=np.linspace(0, 1, 18) + k,
            rel_pos_body_m=[1.0, -0.5, 0.0],
            moving_setpoint_world_m=[k + 1, 0, 2],
            pos_world_m=[k, 0.5, 2.0],
            reward=0.25,
            reward_terms={"d_now_m": 1.1, "collided": False},
            progress_m=float(k),
            deviation_m=0.5,
            latency_ms=20.0 + k,
        )
        rec.vehicle(t, True, "OFFBOARD", {"gyro_ok": True})
    rec.event(t0 + 3.5, "failsafe", "link lost", level="warning", duration_s=0.5)


@pytest.fixture(params=["thread", "process"])
def writer(request) -> str:
    """Both writers: in a thread of this process and in a child process (the daemon's)."""
    return request.param


def test_everything_recorded_comes_back(tmp_path, writer):
    """Each recorder method's data is read back with the values, units and times it was given."""
    path = tmp_path / "f.mcap"
    meta = {"world": "env01", "model_sha256": "ab"}
    with FlightRecorder(path, metadata=meta, depth_decimation=3, writer=writer) as rec:
        _fill(rec)
        rec.close("goal_reached", {"navigation_distance_m": 9.0}, t_mono_s=60.0)
    r = read_record(path)
    assert r.complete and r.problem is None
    assert r.info == {"world": "env01", "model_sha256": "ab"}
    assert [s["step"] for s in r.steps] == list(range(10))
    np.testing.assert_allclose(r.step_array("q_values")[4], np.linspace(0, 1, 18) + 4)
    np.testing.assert_allclose(r.step_array("pos_world_m")[3], [3, 0.5, 2])
    np.testing.assert_allclose(r.step_array("latency_ms"), 20.0 + np.arange(10))
    # the reward terms given land in the step record's own fields; the one not given is NaN
    assert r.steps[2]["d_now_m"] == 1.1 and r.steps[2]["collided"] is False
    assert math.isnan(r.steps[2]["d_prev_m"])
    np.testing.assert_allclose(r.step_t_s, 50.0 + np.arange(10))
    np.testing.assert_allclose(r.odom_pos_world_m[:, 0], np.arange(10))
    np.testing.assert_allclose(r.setpoint_yaw_rad, 0.1 * np.arange(10))
    assert [s for _, s, _ in r.network_inputs] == list(range(10))
    assert r.network_inputs[7][2].dtype == np.float32 and r.network_inputs[7][2][0, 0] == pytest.approx(0.07)
    # depth decimation 3 keeps frames 0, 3, 6, 9, exactly as given
    assert [int(img[0, 0]) for _, img in r.depth] == [1000, 1003, 1006, 1009]
    assert r.depth[1][1].dtype == np.uint16 and r.depth[1][1].shape == (24, 32)
    assert r.vehicle[0]["mode"] == "OFFBOARD" and r.vehicle[0]["armed"] is True
    assert r.events[0]["kind"] == "failsafe" and r.events[0]["level"] == 3
    assert r.events[0]["fields"] == {"duration_s": 0.5}
    np.testing.assert_allclose(r.path_waypoints_m, [[0, 0, 2], [20, 0, 2]])
    assert r.stop["stop_reason"] == "goal_reached" and r.stop["t_mono_s"] == pytest.approx(60.0)
    assert r.stop["summary"] == {"navigation_distance_m": 9.0}


def test_record_is_a_standard_mcap_with_foxglove_schemas(tmp_path, writer):
    """The stock mcap reader opens the record, CRCs hold, and topics carry Foxglove's well-known
    schemas in protobuf (quadnav's own in JSON)."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={}, writer=writer) as rec:
        _fill(rec, n=3)
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        summary = reader.get_summary()
        topics = {c.topic: summary.schemas[c.schema_id].name for c in summary.channels.values()}
        encodings = {
            c.topic: (c.message_encoding, summary.schemas[c.schema_id].encoding)
            for c in summary.channels.values()
        }
        n = sum(1 for _ in reader.iter_messages())
    assert topics == TOPICS
    assert topics["/camera/depth"] == "foxglove.RawImage" and topics["/events"] == "foxglove.Log"
    for topic, name in topics.items():
        protobuf = name in PROTOBUF_SCHEMAS or name in QUADNAV_PROTOBUF
        want = ("protobuf", "protobuf") if protobuf else ("json", "jsonschema")
        assert protobuf or name in JSON_SCHEMAS
        assert encodings[topic] == want, topic
    assert summary.chunk_indexes and all(ci.compression == "zstd" for ci in summary.chunk_indexes)
    assert n == summary.statistics.message_count > 0


def _stall_writer(rec: FlightRecorder) -> tuple[threading.Event, threading.Event]:
    """Make the writer thread block inside its first delivery until released (a slow disk)."""
    entered, release = threading.Event(), threading.Event()
    real = rec._deliver

    def slow(batch):
        entered.set()
        release.wait(timeout=30)
        real(batch)

    rec._deliver = slow  # type: ignore[method-assign]
    return entered, release


def test_stalled_writer_drops_depth_first_and_keeps_all_control_data(tmp_path, writer):
    """Disk stalled: calls still return; depth frames are dropped and counted, control data is not."""
    rec = FlightRecorder(
        tmp_path / "f.mcap", metadata={}, depth_decimation=1, queue_size=1000, image_queue_size=4,
        writer=writer,
    )
    entered, release = _stall_writer(rec)
    rec.event(1.0, "first", "blocks the writer")
    assert entered.wait(timeout=10)
    for k in range(50):
        rec.depth(1.0 + k, np.zeros((8, 8), np.uint16))
        rec.vehicle(1.0 + k, True, "OFFBOARD", {})
    assert rec.drop_counts["depth"] == 46 and rec.drop_counts["control"] == 0
    release.set()
    rec.close("operator_stop", {})
    r = read_record(tmp_path / "f.mcap")
    assert len(r.vehicle) == 50 and len(r.depth) == 4
    assert r.stop["dropped"]["depth"] == 46


def test_control_data_is_dropped_only_when_its_queue_is_full(tmp_path, writer):
    """A writer stalled past ``queue_size`` control messages drops the excess and counts it apart."""
    rec = FlightRecorder(tmp_path / "f.mcap", metadata={}, queue_size=10, writer=writer)
    entered, release = _stall_writer(rec)
    rec.event(1.0, "first", "blocks the writer")
    assert entered.wait(timeout=10)
    for k in range(25):
        rec.event(2.0 + k, "e", str(k))
    assert rec.drop_counts["control"] == 15 and rec.dropped == 15
    release.set()
    rec.close("operator_stop", {})
    assert len(read_record(tmp_path / "f.mcap").events) == 11


def test_write_error_is_contained(tmp_path):
    """A failing disk never raises into the caller: the error is kept and later calls are counted."""
    rec = FlightRecorder(tmp_path / "f.mcap", metadata={})

    def broken(*a, **k):
        raise OSError(28, "No space left on device")

    rec._backend.sink._writer.add_message = broken  # type: ignore[union-attr]
    rec.event(1.0, "x", "y")
    rec.close("crash", {})  # waits for the writer, which failed
    assert isinstance(rec.error, OSError)
    rec.event(2.0, "x", "after")
    assert rec.drop_counts["failed"] >= 1


def test_bad_input_is_counted_not_raised(tmp_path, writer):
    """A NaN time, a wrong-shaped image or a NaN in a message is dropped as invalid, counted in the
    record's stop, and the rest of the record is intact."""
    with FlightRecorder(tmp_path / "f.mcap", metadata={}, depth_decimation=1, writer=writer) as rec:
        rec.event(float("nan"), "x", "nan time")
        rec.depth(1.0, np.zeros((2, 3, 4), np.uint16))
        rec.odometry(1.5, [np.nan, 0, 0], [1, 0, 0, 0])
        rec.event(2.0, "ok", "kept")
        rec.close("operator_stop", {})
        assert rec.drop_counts["invalid"] == 3
    r = read_record(tmp_path / "f.mcap")
    assert [e["kind"] for e in r.events] == ["ok"]
    assert r.stop["dropped"]["invalid"] == 3


def test_unwritable_path_is_a_clear_error(tmp_path):
    """A record that cannot be created raises RecorderError naming the path."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(RecorderError, match="cannot create flight record") as err:
        FlightRecorder(blocker / "sub" / "f.mcap", metadata={})
    assert str(blocker) in str(err.value)


def test_a_record_is_never_opened_over_an_existing_file(tmp_path, writer):
    """A record is created exclusively: a file already at its path (a quick restart's previous
    flight) is refused and left as it was."""
    path = tmp_path / "f.mcap"
    path.write_bytes(b"the previous flight")
    with pytest.raises(RecordExistsError, match="the file exists"):
        FlightRecorder(path, metadata={}, writer=writer)
    assert path.read_bytes() == b"the previous flight"


def test_flights_started_together_get_records_of_their_own(tmp_path, writer):
    """Flights started together get a record each: names carry microseconds, and recorders opened
    for the very same instant take the next free suffix; every record reads back."""
    t = 1_764_655_200.123456
    recs = [FlightRecorder.new_in(tmp_path, t_unix_s=t, metadata={"n": n}, writer=writer) for n in "012"]
    for rec in recs:
        rec.close("ok", {})
    names = [rec.path.name for rec in recs]
    assert names == [
        "flight-20251202-060000.123456.mcap",
        "flight-20251202-060000.123456-2.mcap",
        "flight-20251202-060000.123456-3.mcap",
    ]
    assert [read_record(rec.path).info["n"] for rec in recs] == ["0", "1", "2"]


def test_record_names_sort_by_time_to_the_microsecond():
    assert record_name(1_764_655_200.0) < record_name(1_764_655_200.000002) < record_name(1_764_655_201.0)
    assert record_name(1_764_655_200.5, 7) == "flight-20251202-060000.500000-7.mcap"


def test_null_recorder_has_the_recorders_methods():
    """NullRecorder can stand in for FlightRecorder: every public method exists and does nothing."""
    constructors = {"new_in"}
    public = {n for n in dir(FlightRecorder) if not n.startswith("_")} - {"error"} - constructors
    missing = {n for n in public if not hasattr(NullRecorder, n)}
    assert not missing
    NullRecorder().close("x", {})


def test_other_mcap_files_are_refused(tmp_path):
    """An MCAP file that is not a quadnav record, a text file and a folder are refused with one line."""
    other = tmp_path / "other.mcap"
    with open(other, "wb") as f:
        w = Writer(f)
        w.start()
        sid = w.register_schema("x", "jsonschema", b"{}")
        cid = w.register_channel("/x", "json", sid)
        w.add_message(cid, log_time=1, data=b"{}", publish_time=1)
        w.finish()
    with pytest.raises(RecordError, match="not a quadnav flight record"):
        read_record(other)
    (tmp_path / "t.mcap").write_text("hello")
    with pytest.raises(RecordError, match="not an MCAP file"):
        read_record(tmp_path / "t.mcap")
    with pytest.raises(RecordError, match="not a regular file"):
        read_record(tmp_path)


def test_calls_from_several_threads_are_all_recorded(tmp_path, writer):
    """The recorder is thread-safe: events from four threads all arrive, none dropped or duplicated."""
    path = tmp_path / "f.mcap"
    rec = FlightRecorder(path, metadata={}, writer=writer)

    def worker(i: int) -> None:
        for k in range(300):
            rec.event(1.0 + k * 1e-3, f"w{i}", str(k))

    threads = [threading.Thread(target=worker, args=(i,)) for i in range(4)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    rec.close("operator_stop", {})
    assert rec.dropped == 0
    events = read_record(path).events
    assert len(events) == 1200
    for i in range(4):
        assert sorted(int(e["message"]) for e in events if e["kind"] == f"w{i}") == list(range(300))


def test_the_shields_verdict_is_recorded_with_its_step_and_absent_without_it(tmp_path):
    """A step flown with the depth safety filter carries which primitives it allowed and their
    clearances; a step without it has neither (None)."""
    path = tmp_path / "f.mcap"
    allowed = np.arange(18) % 3 != 0
    clearance = np.linspace(0.1, 1.5, 18)
    common = dict(
        q_values=np.zeros(18), rel_pos_body_m=[1, 0, 0], moving_setpoint_world_m=[1, 0, 2],
        pos_world_m=[0, 0, 2], reward=0.1, reward_terms={}, progress_m=0.0, deviation_m=0.0, latency_ms=1.0,
    )
    with FlightRecorder(path, metadata={}) as rec:
        rec.step(1.0, step=0, action=1, shield_allowed=allowed, shield_clearance_m=clearance, **common)
        rec.step(2.0, step=1, action=2, **common)
        rec.close("goal_reached", {}, t_mono_s=3.0)
    steps = read_record(path).steps
    assert steps[0]["shield_allowed"] == allowed.tolist()
    np.testing.assert_allclose(steps[0]["shield_clearance_m"], clearance)
    assert steps[1]["shield_allowed"] is None and steps[1]["shield_clearance_m"] is None
