"""End to end: a dry-run flight (real daemon, real MAVSDK, emulated PX4) leaves a record whose
review prints exactly the row the daemon printed at the end of the flight."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.record import RecordError, read_record

SHORT_WORLD = """\
name: short-free
description: a 5 m obstacle-free corridor for a quick dry run
path: {waypoints: [[0, 0, 2], [5, 0, 2]], speed_m_s: 1.0}
bounds: {floor_z: 0.0, ceiling_z: 6.0}
"""


def _dry_run_cmd(world: Path, model: Path, rec_dir: Path) -> list[str]:
    """``quadnav-onboard --dry-run`` of ``world`` with ``model``, recording into ``rec_dir``."""
    return [
        sys.executable,
        "-m",
        "quadnav_onboard.cli",
        "--dry-run",
        "--world",
        str(world),
        "--model",
        str(model),
        "--record-dir",
        str(rec_dir),
        "--log-format",
        "json",
    ]


@pytest.mark.e2e
@pytest.mark.slow
def test_dry_run_record_reviews_to_the_row_the_daemon_printed(tmp_path):
    """The review's row equals the daemon's printed row; the record holds the whole flight."""
    model = tmp_path / "straight.pt"
    constant_action_checkpoint(str(model), action=4)
    world = tmp_path / "short.yaml"
    world.write_text(SHORT_WORLD)
    rec_dir = tmp_path / "records"
    flight = subprocess.run(
        _dry_run_cmd(world, model, rec_dir),
        capture_output=True,
        text=True,
        timeout=150,
        check=False,
    )
    assert flight.returncode == 0, flight.stderr[-2000:]
    daemon_row = flight.stdout.splitlines()[0]
    assert daemon_row.startswith("navigation distance ") and "stop: goal_reached" in daemon_row
    records = sorted(rec_dir.glob("*.mcap"))
    assert len(records) == 1

    review = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.review.cli", str(records[0])],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert review.returncode == 0, review.stderr
    assert review.stdout.splitlines()[1] == daemon_row
    assert "warning" not in review.stderr  # the summary agrees with the recorded decisions

    rec = read_record(records[0])
    assert rec.complete and rec.stop["stop_reason"] == "goal_reached"
    assert not any((rec.stop.get("dropped") or {}).values())
    n = rec.stop["summary"]["steps"]
    assert [s["step"] for s in rec.steps] == list(range(n))
    assert sorted(s for _, s, _ in rec.network_inputs) == list(range(n))
    assert len(rec.depth) > 0 and len(rec.odom_t_s) > 10 * n and len(rec.setpoint_t_s) > 10 * n
    assert "OFFBOARD" in {v["mode"] for v in rec.vehicle}
    assert rec.info["model_sha256"] and rec.path_waypoints_m is not None

    as_json = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.review.cli", str(records[0]), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    row = json.loads(as_json.stdout)
    assert row["world"] == "short-free" and row["source"] == "summary" and row["reached_goal"] is True


@pytest.mark.e2e
@pytest.mark.slow
@pytest.mark.parametrize("victims", ["all", "daemon"])
def test_kill_9_of_the_daemon_mid_flight_leaves_a_reviewable_record(tmp_path, victims):
    """SIGKILL of a flying dry run. ``all``: the daemon and its record writer process die together
    (power loss, systemd's final kill): the record is read up to its last chunk. ``daemon``: the
    writer outlives it and finishes the record, stop reason ``flight_process_lost``. Either way the
    review prints the row from the recorded decisions."""
    model = tmp_path / "straight.pt"
    constant_action_checkpoint(str(model), action=4)
    world = tmp_path / "long.yaml"
    world.write_text(SHORT_WORLD.replace("[5, 0, 2]", "[40, 0, 2]"))
    rec_dir = tmp_path / "records"
    daemon = subprocess.Popen(
        _dry_run_cmd(world, model, rec_dir),
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,
        env={**os.environ, "TMPDIR": str(tmp_path)},  # the killed stand-ins' logs stay in tmp_path
    )
    steps_seen = 0
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and steps_seen < 4 and daemon.poll() is None:
            time.sleep(0.5)
            for path in rec_dir.glob("*.mcap"):
                with contextlib.suppress(RecordError):
                    steps_seen = len(read_record(path, load_depth=False).steps)
    finally:
        if victims == "all":
            os.killpg(daemon.pid, signal.SIGKILL)
        else:
            os.kill(daemon.pid, signal.SIGKILL)
        daemon.wait(timeout=10)
    assert steps_seen >= 4 and daemon.returncode == -signal.SIGKILL
    (path,) = rec_dir.glob("*.mcap")
    if victims == "daemon":  # the writer process finishes the file on its own
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not read_record(path, load_depth=False).complete:
            time.sleep(0.2)
    review = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.review.cli", str(path), "--json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert review.returncode == 0, review.stderr
    row = json.loads(review.stdout)
    if victims == "all":
        assert row["complete"] is False and row["stop_reason"] == "(cut off)"
    else:
        assert row["complete"] is True and row["stop_reason"] == "flight_process_lost"
        assert "without closing the record" in row["detail"]
    assert row["source"] == "steps"
    assert row["steps"] >= 4 and 2.0 < row["navigation_distance_m"] < 40.0
