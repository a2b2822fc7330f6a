"""The step module: inputs, rollout, outcome, reward and history of one planner step."""

from __future__ import annotations

import numpy as np
import pytest

from quadnav_onboard import step
from quadnav_onboard.config import PrimitiveConfig
from quadnav_onboard.frames import body_to_world
from quadnav_onboard.path import RoughPath
from quadnav_onboard.reward import RewardParams

PATH = RoughPath.straight([0.0, 0.0, 2.0], [20.0, 0.0, 2.0], speed_m_s=1.0)
LIMITS = step.EpisodeLimits(goal_radius_m=1.0, episode_deviation_m=5.0, max_steps=30)


def _finish(pos0, pos1, k=0, collided=False, limits=LIMITS, params=RewardParams()):
    before = step.step_inputs(PATH, k, 1.0, pos0)
    after = step.step_inputs(PATH, k + 1, 1.0, pos1)
    return step.finish_step(before, after, step=k, action=0, q_values=None, pos_world_m=pos0,
                            end_pos_world_m=pos1, collided=[collided], path=PATH, limits=limits,
                            reward_params=params, n_actions=18)


def test_inputs_are_the_setpoint_in_the_heading_frame():
    """Step k's setpoint is k*duration along the path; the relative state is in the path's frame."""
    inputs = step.step_inputs(PATH, [3, 5], 1.0, [[1.0, 1.0, 2.0], [5.0, -2.0, 1.0]])
    np.testing.assert_allclose(inputs.setpoint_world_m, [[3.0, 0.0, 2.0], [5.0, 0.0, 2.0]])
    np.testing.assert_allclose(inputs.rel_pos_body_m, [[2.0, -1.0, 0.0], [0.0, 2.0, 1.0]])
    np.testing.assert_allclose(inputs.distance_m, [np.sqrt(5.0), np.sqrt(5.0)])
    np.testing.assert_allclose(inputs.deviation_m, [1.0, np.sqrt(5.0)])
    np.testing.assert_allclose(inputs.progress_m, [1.0, 5.0])


def test_goal_within_the_radius_or_at_the_paths_end():
    near = _finish([18.0, 0.0, 2.0], [19.05, 0.0, 2.0])
    short = _finish([17.0, 0.0, 2.0], [18.9, 0.5, 2.0])
    past = _finish([19.0, 3.0, 2.0], [22.0, 3.0, 2.0])
    assert near.outcome_label() == "goal" and past.outcome_label() == "goal"
    assert short.outcome_label() is None


def test_deviation_past_the_episode_limit_ends_with_the_penalty():
    at = _finish([5.0, 4.0, 2.0], [6.0, 5.0, 2.0])
    past = _finish([5.0, 4.0, 2.0], [6.0, 5.01, 2.0])
    assert at.outcome_label() is None and not at.deviated[0]
    assert past.outcome_label() == "deviation" and past.reward[0] == RewardParams().deviation_penalty


def test_step_limit_counts_steps_flown():
    assert _finish([1.0, 0, 2], [2.0, 0, 2], k=28).outcome_label() is None
    assert _finish([1.0, 0, 2], [2.0, 0, 2], k=29).outcome_label() == "timeout"


def test_a_crash_wins_over_every_other_outcome():
    rec = _finish([18.0, 6.0, 2.0], [19.5, 6.0, 2.0], k=29, collided=True)
    assert rec.outcome_label() == "crash" and rec.reward[0] == RewardParams().collision_penalty
    codes = step.outcome_codes([False, False, False, True], [False, False, True, True],
                               [False, True, True, True], [True, True, True, True])
    assert [step.Outcome(c).label for c in codes] == ["timeout", "goal", "deviation", "crash"]


@pytest.mark.parametrize(("d_prev", "d_now", "expect"), [
    (12.0, 0.5, "upper"),  # closed in by more than the bound: r_upper / max(d_now, floor)
    (0.5, 12.0, "lower"),  # fell behind by more than the bound: r_lower / d_now
])
def test_reward_at_its_bounds(d_prev, d_now, expect):
    """The shaped reward saturates at the distance-change bounds and divides by max(d_now, floor)."""
    p = RewardParams()
    before = step.StepInputs(*(np.array(v) for v in ([[d_prev, 0, 0]], [0.0], [[d_prev, 0, 0]], [d_prev],
                                                     [0.0], [0.0], [10.0])))
    after = step.StepInputs(*(np.array(v) for v in ([[d_now, 0, 0]], [0.0], [[d_now, 0, 0]], [d_now],
                                                    [1.0], [0.0], [10.0])))
    rec = step.finish_step(before, after, step=0, action=0, q_values=None, pos_world_m=[0, 0, 0],
                           end_pos_world_m=[0, 0, 0], collided=[False], path=PATH, limits=LIMITS,
                           reward_params=p, n_actions=18)
    r = p.r_upper if expect == "upper" else p.r_lower
    assert rec.reward[0] == pytest.approx(r / max(d_now, p.d_floor_m))


def test_rollout_starts_at_the_commanded_start_and_ends_at_the_primitives_end():
    prims = PrimitiveConfig().build()
    u = np.array([[0.0], [0.5], [1.0]])
    start, vel0, yaw = np.array([[1.0, 2.0, 3.0]]), np.array([[0.3, 0.0, 0.0]]), np.array([0.7])
    pos, vel = step.primitive_targets(prims, [5], start, vel0, yaw, u)
    np.testing.assert_allclose(pos[0, 0], start[0])
    np.testing.assert_allclose(vel[0, 0], vel0[0], atol=1e-12)
    end = start[0] + body_to_world(prims.end_displacement_m(5), 0.7)
    np.testing.assert_allclose(pos[-1, 0], end, atol=1e-12)


def test_history_drops_the_oldest():
    stack = np.arange(6, dtype=np.float32).reshape(2, 3)[:, :, None]
    out = step.push_history(stack, [[9.0], [8.0]])
    np.testing.assert_array_equal(out[..., 0], [[1, 2, 9], [4, 5, 8]])


def test_a_record_row_and_its_plain_values():
    rec = _finish([[1.0, 0, 2], [2.0, 0, 2]], [[2.0, 0, 2], [3.0, 0, 2]], k=0)
    assert rec.n == 2 and rec.row(1).n == 1
    d = rec.row(1).as_dict()
    assert d["pos_world_m"] == [2.0, 0.0, 2.0] and d["shield_allowed"] is None and d["outcome"] == 0


def test_step_fractions_end_at_the_step_s_end_and_are_never_empty() -> None:
    """1 s at 0.02 s: 50 fractions 0.02 ... 1.0; a step shorter than half a tick still has one."""
    u = step.step_fractions(1.0, 0.02)
    assert u.shape == (50, 1) and u[0, 0] == pytest.approx(0.02) and u[-1, 0] == 1.0
    assert np.all(np.diff(u[:, 0]) > 0)
    assert step.step_fractions(0.005, 0.02).tolist() == [[1.0]]
