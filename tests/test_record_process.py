"""The recorder's writer process: what happens when either side dies or is signalled.

No stubs: real child processes, real signals, real files read back with the reader.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from quadnav_onboard.record import FlightRecorder, RecorderError, read_record
from quadnav_onboard.record.writer_process import LOST_REASON

# A flight that records until it is signalled; SIGTERM (systemctl stop) makes it close the record
# as the daemon does. It prints the writer process's pid, then "go" once data is flowing.
_FLIGHT = textwrap.dedent(
    """
    import signal, sys, time
    import numpy as np
    from quadnav_onboard.record import FlightRecorder
    rec = FlightRecorder(sys.argv[1], metadata={"world": "signal-test"}, flush_interval_s=0.05,
                         writer="process")
    stopping = []
    signal.signal(signal.SIGTERM, lambda *a: stopping.append(1))
    print(rec._backend.proc.pid, flush=True)
    k = 0
    while not stopping:
        t = 100.0 + 0.02 * k
        rec.step(t, step=k, action=4, q_values=np.zeros(18), rel_pos_body_m=[1, 0, 0],
                 moving_setpoint_world_m=[1, 0, 2], pos_world_m=[0.02 * k, 0, 2], reward=0.1,
                 reward_terms={}, progress_m=0.02 * k, deviation_m=0.0, latency_ms=1.0)
        if k == 100:  # ~0.3 s: several batches have crossed to the writer
            print("go", flush=True)
        k += 1
        time.sleep(0.002)
    rec.close("operator_stop", {"steps": k}, t_mono_s=100.0 + 0.02 * k)
    """
)


def _start_flight(path) -> tuple[subprocess.Popen, int]:
    flight = subprocess.Popen(
        [sys.executable, "-c", _FLIGHT, str(path)], stdout=subprocess.PIPE, text=True, start_new_session=True
    )
    assert flight.stdout is not None
    writer_pid = int(flight.stdout.readline())
    assert flight.stdout.readline().strip() == "go"
    return flight, writer_pid


def _wait_gone(pid: int, timeout_s: float = 15.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.kill(pid, 0)
        except ProcessLookupError:
            return
        time.sleep(0.05)
    raise AssertionError(f"process {pid} still running after {timeout_s} s")


def test_systemctl_stop_reaches_the_whole_group_and_the_record_still_ends_with_its_reason(tmp_path):
    """SIGTERM to the process group (what systemd sends to a unit): the writer process ignores it
    and the flight process closes the record with its own stop reason."""
    path = tmp_path / "stopped.mcap"
    flight, writer_pid = _start_flight(path)
    os.killpg(flight.pid, signal.SIGTERM)
    assert flight.wait(timeout=30) == 0
    _wait_gone(writer_pid)
    rec = read_record(path)
    assert rec.complete and rec.stop["stop_reason"] == "operator_stop"
    steps = [s["step"] for s in rec.steps]
    assert steps == list(range(len(steps))) and rec.stop["summary"]["steps"] == len(steps)


def test_flight_process_killed_alone_the_writer_finishes_the_record(tmp_path):
    """kill -9 of the flight process only: the writer process sees its input end, writes what it
    was given and finishes the file, with a stop reason that says the flight process was lost.
    What was still queued in the flight process (at most one batch interval, 50 ms) is lost."""
    path = tmp_path / "orphan.mcap"
    flight, writer_pid = _start_flight(path)
    os.kill(flight.pid, signal.SIGKILL)
    flight.wait(timeout=10)
    _wait_gone(writer_pid)
    rec = read_record(path)
    assert rec.complete and rec.problem is None
    assert rec.stop["stop_reason"] == LOST_REASON
    steps = [s["step"] for s in rec.steps]
    assert len(steps) > 20 and steps == list(range(len(steps)))


def test_writer_process_killed_mid_flight_is_contained(tmp_path):
    """The writer process dies: the caller never sees an exception, the recorder says why it
    stopped, later calls are counted as failed, close() returns, and what was flushed is readable."""
    path = tmp_path / "f.mcap"
    rec = FlightRecorder(path, metadata={}, flush_interval_s=0.05, writer="process")
    for k in range(50):
        rec.event(1.0 + k, "e", str(k))
    time.sleep(0.5)  # past a flush
    rec._backend.proc.kill()
    rec._backend.proc.wait(timeout=10)
    deadline = time.monotonic() + 10
    while rec.error is None and time.monotonic() < deadline:
        rec.event(99.0, "e", "after")
        time.sleep(0.02)
    assert isinstance(rec.error, OSError) and "writer process" in str(rec.error)
    rec.event(100.0, "e", "after the failure")
    assert rec.drop_counts["failed"] >= 1
    t0 = time.monotonic()
    rec.close("operator_stop", {})
    assert time.monotonic() - t0 < 5.0
    r = read_record(path)
    assert not r.complete and [e["message"] for e in r.events[:50]] == [str(k) for k in range(50)]


def test_a_writer_process_that_cannot_start_is_a_clear_error(tmp_path, monkeypatch):
    """No usable interpreter for the writer: RecorderError names the record, before any flight."""
    monkeypatch.setattr(sys, "executable", "/bin/false")
    with pytest.raises(RecorderError, match="writer process did not start") as err:
        FlightRecorder(tmp_path / "f.mcap", metadata={}, writer="process")
    assert str(tmp_path / "f.mcap") in str(err.value)


def test_unpicklable_event_fields_are_dropped_as_invalid_not_the_batch(tmp_path):
    """An event field that cannot cross to the writer process is counted invalid; the rest arrives."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={}, writer="process") as rec:
        rec.event(1.0, "ok", "before")
        rec.event(1.5, "bad", "a lambda", fn=lambda: None)
        rec.event(2.0, "ok", "after")
        rec.close("operator_stop", {})
        assert rec.drop_counts["invalid"] == 1
    assert [e["message"] for e in read_record(path).events] == ["before", "after"]


def test_writer_process_records_big_depth_frames_intact(tmp_path):
    """Full-size D435 frames (848x480 uint16) cross the pipe and come back bit for bit."""
    path = tmp_path / "f.mcap"
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 10_000, (480, 848), dtype=np.uint16) for _ in range(3)]
    with FlightRecorder(path, metadata={}, depth_decimation=1, writer="process") as rec:
        for k, f in enumerate(frames):
            rec.depth(1.0 + k, f)
            time.sleep(0.05)  # the image queue sheds frames that outrun the writer
        rec.close("operator_stop", {})
        assert rec.dropped == 0
    got = read_record(path).depth
    assert len(got) == 3 and all(np.array_equal(g, f) for (_, g), f in zip(got, frames, strict=True))


def test_a_garbled_first_frame_is_reported_on_the_status_line(tmp_path):
    """The writer process answers bytes that are not a frame with one ``failed`` status line and
    exit code 1, never a traceback (the recorder turns it into a RecorderError)."""
    import json

    fd = os.open(tmp_path / "f.mcap", os.O_WRONLY | os.O_CREAT)
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", "quadnav_onboard.record.writer_process", str(fd)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            pass_fds=(fd,),
        )
        out, err = proc.communicate(b"\x05\x00\x00\x00garbage", timeout=30)
    finally:
        os.close(fd)
    assert proc.returncode == 1 and b"Traceback" not in err
    (line,) = out.decode().splitlines()
    assert "UnpicklingError" in json.loads(line)["failed"]
