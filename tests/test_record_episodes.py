"""Sim episodes written with record_sim_episode are ordinary flight records the review reads."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav_onboard.record import read_record
from quadnav_onboard.record.episodes import SimStep, record_sim_episode
from quadnav_onboard.review.table import row_from_record


def test_sim_episode_round_trips_with_its_row(tmp_path):
    """Decisions, trail and summary come back; the row is the summary's; missing Q-values stay NaN."""
    steps = [
        SimStep(
            action=4,
            pos_world_m=[k, 0, 2],
            moving_setpoint_world_m=[k + 1, 0, 2],
            rel_pos_body_m=[1, 0, 0],
            reward=0.5,
            progress_m=k + 1.0,
            deviation_m=0.0,
            input_32=np.full((32, 32), 0.5, np.float32),
            q_values=None if k == 2 else np.arange(18.0),
        )
        for k in range(4)
    ]
    trail = np.stack([np.linspace(0, 4, 41), np.zeros(41), np.full(41, 2.0)], axis=1)
    summary = {
        "navigation_distance_m": 4.0,
        "navigation_time_s": 4.0,
        "crashed": False,
        "total_reward": 2.0,
        "steps": 4,
    }
    path = record_sim_episode(
        tmp_path / "ep.mcap",
        steps=steps,
        stop_reason="goal_reached",
        summary=summary,
        waypoints_world_m=[[0, 0, 2], [4, 0, 2]],
        metadata={"world": "env01", "trial": "3"},
        trail_world_m=trail,
        trail_dt_s=0.1,
    )
    rec = read_record(path)
    assert rec.complete and rec.info["world"] == "env01" and rec.info["mode"] == "sim"
    np.testing.assert_allclose(rec.step_t_s, 1000.0 + np.arange(4))
    np.testing.assert_allclose(rec.odom_t_s, 1000.0 + 0.1 * np.arange(41))
    np.testing.assert_allclose(rec.odom_pos_world_m, trail)
    q = rec.step_array("q_values")
    assert np.isnan(q[2]).all() and q[1, 5] == 5.0
    assert len(rec.network_inputs) == 4
    row = row_from_record(rec)
    assert row.source == "summary" and row.reached_goal and not row.crashed
    assert row.navigation_distance_m == pytest.approx(4.0) and row.total_reward == pytest.approx(2.0)
