"""quadnav-review: the paper's row and table, JSON, warnings, and clean errors for bad records."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quadnav_onboard.record import FlightRecorder, read_record
from quadnav_onboard.record.synthetic import write_synthetic_flight
from quadnav_onboard.review.cli import main
from quadnav_onboard.review.table import format_row, row_from_record, row_from_summary


@pytest.fixture(scope="module")
def flights(tmp_path_factory):
    d = tmp_path_factory.mktemp("flights")
    ok = write_synthetic_flight(d / "ok.mcap", depth_hz=4.0, seed=3)
    crash = write_synthetic_flight(d / "crash.mcap", crash_at_step=10, depth_hz=4.0, seed=4)
    return d, ok, crash


def test_printed_row_is_the_daemons_summary(flights, capsys):
    """The row printed for a record equals the row formatted from the summary given at close()."""
    d, ok, _ = flights
    assert main([str(d / "ok.mcap")]) == 0
    out = capsys.readouterr().out.splitlines()
    expected = format_row(row_from_summary(ok, stop_reason=ok["stop_reason"]))
    assert out[1] == expected
    assert "30.00" in expected or f"{ok['navigation_distance_m']:.2f}" in expected


def test_json_row_carries_the_summary_numbers(flights, capsys):
    """--json gives the row's numbers exactly as the daemon summarised them, and the stop reason."""
    d, _, crash = flights
    assert main([str(d / "crash.mcap"), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)
    for key in ("navigation_distance_m", "navigation_time_s", "total_reward", "steps"):
        assert row[key] == pytest.approx(crash[key])
    assert row["crashed"] is True and row["stop_reason"] == "crash" and row["reached_goal"] is False
    assert row["complete"] is True and row["source"] == "summary"


def test_several_records_give_the_table_with_rates(flights, capsys):
    """A folder of records prints one row per flight and the success / collision-free rates."""
    d, _, _ = flights
    assert main([str(d)]) == 0
    out = capsys.readouterr().out
    assert out.count("synthetic-box") == 2
    assert "2 trials: success  50%, collision-free  50%, success among collision-free 100%" in out
    assert main([str(d), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert len(data["rows"]) == 2 and data["rates"]["collision_free_rate"] == 0.5


def test_row_is_computed_from_decisions_when_summary_is_missing(tmp_path):
    """Without a summary, distance = furthest progress, reward = sum, time = first decision to stop."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={"world": "w"}) as rec:
        for k in range(5):
            rec.step(
                10.0 + k,
                step=k,
                action=4,
                q_values=np.zeros(18),
                rel_pos_body_m=[1, 0, 0],
                moving_setpoint_world_m=[k, 0, 2],
                pos_world_m=[k, 0, 2],
                reward=0.5 - 0.1 * k,
                reward_terms={},
                progress_m=[0.0, 1.0, 3.0, 2.5, 2.0][k],
                deviation_m=0.0,
                latency_ms=5.0,
            )
        rec.close("crash", {}, t_mono_s=15.0)
    row = row_from_record(read_record(path))
    assert row.source == "steps"
    assert row.navigation_distance_m == pytest.approx(3.0)
    assert row.total_reward == pytest.approx(1.5)
    assert row.navigation_time_s == pytest.approx(5.0)
    assert row.crashed and not row.reached_goal and row.steps == 5


def test_summary_that_disagrees_with_the_decisions_is_flagged(tmp_path, capsys):
    """A summary whose distance differs from the recorded progress produces a warning on stderr."""
    path = tmp_path / "f.mcap"
    with FlightRecorder(path, metadata={}) as rec:
        rec.step(
            1.0,
            step=0,
            action=4,
            q_values=np.zeros(18),
            rel_pos_body_m=[1, 0, 0],
            moving_setpoint_world_m=[0, 0, 2],
            pos_world_m=[0, 0, 2],
            reward=0.1,
            reward_terms={},
            progress_m=2.0,
            deviation_m=0.0,
            latency_ms=5.0,
        )
        rec.close("step_limit", {"navigation_distance_m": 9.0}, t_mono_s=2.0)
    assert main([str(path)]) == 0
    err = capsys.readouterr().err
    assert "navigation_distance_m=9.00 differs from the recorded decisions (2.00)" in err


def test_bad_records_give_one_line_errors_and_the_rest_is_reviewed(flights, tmp_path, capsys):
    """Missing, non-MCAP, truncated-header and empty-folder inputs: one line each, exit 1, no traceback."""
    d, _, _ = flights
    text = tmp_path / "notes.mcap"
    text.write_text("not a record")
    stub = tmp_path / "stub.mcap"
    stub.write_bytes((d / "ok.mcap").read_bytes()[:12])
    empty = tmp_path / "empty"
    empty.mkdir()
    code = main([str(tmp_path / "missing.mcap"), str(text), str(stub), str(empty), str(d / "ok.mcap")])
    out, err = capsys.readouterr()
    assert code == 1
    lines = err.strip().splitlines()
    assert len(lines) == 4 and all(line.startswith("quadnav-review: ") for line in lines)
    assert "no such file" in lines[0] and "not an MCAP file" in lines[1]
    assert "stub.mcap" in lines[2] and "no .mcap records" in lines[3]
    assert "Traceback" not in err and "ok.mcap" in out


def test_world_file_is_drawn_when_the_record_has_none(tmp_path, capsys):
    """--world adds a world to a record without one (real flights); a bad world file is a usage error."""
    path = tmp_path / "real.mcap"
    with FlightRecorder(path, metadata={"model_sha256": "ab"}) as rec:
        rec.odometry(1.0, [0, 0, 1], [1, 0, 0, 0])
        rec.close("operator_stop", {}, t_mono_s=2.0)
    world = tmp_path / "arena.yaml"
    world.write_text(
        "name: arena\npath: {waypoints: [[0, 0, 1], [3.5, 0, 1]]}\nobstacles:\n"
        "  - {type: box, center: [2, 0, 1], size: [0.5, 1, 2]}\n"
    )
    out = tmp_path / "r.html"
    assert main([str(path), "--world", str(world), "--html", str(out), "-q"]) == 0
    assert "quadnav.world_yaml" in out.read_text() and "type: box" in out.read_text()
    bad = tmp_path / "bad.yaml"
    bad.write_text("- not a mapping\n")
    assert main([str(path), "--world", str(bad)]) == 2
    assert "a world file must be a YAML mapping" in capsys.readouterr().err
