"""A record cut off mid-flight (SIGKILL, power loss) is still read up to its last whole chunk."""

from __future__ import annotations

import io
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
from mcap.reader import make_reader

from quadnav_onboard.record import FlightRecorder, RecordError, read_record
from quadnav_onboard.review.cli import main as review_main

_CHILD = textwrap.dedent(
    """
    import sys, time
    import numpy as np
    from quadnav_onboard.record import FlightRecorder
    rec = FlightRecorder(sys.argv[1], metadata={"world": "kill-test"}, flush_interval_s=0.05,
                         chunk_size=4096, writer=sys.argv[2])
    k = 0
    while True:  # a flight that never ends on its own: it is killed with SIGKILL
        t = 100.0 + 0.02 * k
        rec.odometry(t, [0.02 * k, 0, 2], [1, 0, 0, 0])
        rec.step(t, step=k, action=4, q_values=np.zeros(18), rel_pos_body_m=[1, 0, 0],
                 moving_setpoint_world_m=[1, 0, 2], pos_world_m=[0.02 * k, 0, 2], reward=0.1,
                 reward_terms={}, progress_m=0.02 * k, deviation_m=0.0, latency_ms=10.0)
        k += 1
        time.sleep(0.002)
    """
)


@pytest.mark.parametrize("writer", ["thread", "process"])
def test_kill_9_mid_flight_leaves_a_readable_record(tmp_path, capsys, writer):
    """kill -9 of a recording process (and of its writer process, as a power cut or systemd's final
    kill of the unit does): the record reads, marked cut off, decisions 0..n-1 intact."""
    path = tmp_path / "killed.mcap"
    child = subprocess.Popen([sys.executable, "-c", _CHILD, str(path), writer], start_new_session=True)
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and (not path.exists() or path.stat().st_size < 20_000):
            time.sleep(0.05)
        assert path.stat().st_size >= 20_000, "the child never flushed data"
    finally:
        os.killpg(child.pid, signal.SIGKILL)
        child.wait(timeout=10)
    assert child.returncode == -signal.SIGKILL
    rec = read_record(path)
    assert not rec.complete and rec.stop is None and rec.problem
    steps = [s["step"] for s in rec.steps]
    assert len(steps) > 10 and steps == list(range(len(steps)))
    assert rec.info["world"] == "kill-test"
    assert review_main([str(path)]) == 0
    out = capsys.readouterr()
    assert "CUT OFF" in out.out and "(cut off)" in out.out
    assert "incomplete" in out.err


@pytest.fixture(scope="module")
def complete_record(tmp_path_factory) -> tuple[bytes, int]:
    path = tmp_path_factory.mktemp("rec") / "full.mcap"
    with FlightRecorder(path, metadata={"world": "w"}, chunk_size=2048) as rec:
        for k in range(200):
            rec.step(
                100.0 + k,
                step=k,
                action=1,
                q_values=np.arange(18.0),
                rel_pos_body_m=[1, 0, 0],
                moving_setpoint_world_m=[k, 0, 2],
                pos_world_m=[k, 0, 2],
                reward=0.5,
                reward_terms={},
                progress_m=float(k),
                deviation_m=0.0,
                latency_ms=5.0,
            )
        rec.close("step_limit", {}, t_mono_s=300.0)
    return path.read_bytes(), 200


def test_truncated_anywhere_reads_a_prefix_or_fails_cleanly(tmp_path, complete_record):
    """Cut at any byte, the reader returns a prefix of the decisions (never garbage) or a RecordError."""
    data, n = complete_record
    seen_partial = 0
    for cut in np.linspace(1, len(data) - 1, 97).astype(int):
        p = tmp_path / f"cut{cut}.mcap"
        p.write_bytes(data[:cut])
        try:
            rec = read_record(p)
        except RecordError as exc:
            assert str(p) in str(exc)
            continue
        steps = [s["step"] for s in rec.steps]
        assert steps == list(range(len(steps))) and len(steps) <= n
        assert not rec.complete
        seen_partial += 0 < len(steps) < n
    assert seen_partial > 20


def test_flipped_byte_in_a_chunk_stops_at_the_damage(tmp_path, complete_record):
    """A corrupted chunk fails its CRC: the record is read up to it and says where it is damaged."""
    data, n = complete_record
    chunks = make_reader(io.BytesIO(data)).get_summary().chunk_indexes
    middle = chunks[len(chunks) // 2]
    bad = bytearray(data)
    bad[middle.chunk_start_offset + middle.chunk_length // 2] ^= 0xFF
    p = tmp_path / "bad.mcap"
    p.write_bytes(bytes(bad))
    rec = read_record(p)
    steps = [s["step"] for s in rec.steps]
    assert steps == list(range(len(steps))) and 0 < len(steps) < n
    assert rec.problem and ("corrupt" in rec.problem or "cut off" in rec.problem)
