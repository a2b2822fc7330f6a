"""The privileged teacher: its cost-to-go field and its labels where the answer is known."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.config import ConfigError, TrainConfig, load_train_config
from sim_harness.rl.teacher import (
    UNREACHABLE,
    Teacher,
    TeacherConfig,
    cost_field,
    soft_targets,
    teacher_config,
    vetoed_as_crashes,
)
from sim_harness.world import parse_world

FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))


def _world(obstacles: list[dict], length: float = 20.0):
    return parse_world({
        "name": "test",
        "path": {"waypoints": [[0.0, 0.0, 2.0], [length, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": obstacles,
    })


def _env(world, n: int = 1) -> VecQuadNavEnv:
    env = VecQuadNavEnv([world], n, seed=0, config=EnvConfig(start_jitter_m=0.0), autoreset=False)
    env.reset()
    return env


def test_field_in_free_space_is_the_distance_to_the_goal_ball() -> None:
    world = _world([])
    field = cost_field(world, 0.3, TeacherConfig(grid_m=0.25))
    pts = np.array([[0.0, 0.0, 2.0], [10.0, 1.0, 2.0], [15.0, -2.0, 1.5]])
    straight = np.linalg.norm(pts - world.path.goal_m, axis=1) - 0.9
    got = field(pts)
    # a 26-neighbour grid overestimates a straight line by at most ~8 % (and never under)
    assert np.all(got >= straight - 0.3) and np.all(got <= 1.09 * straight + 0.3)
    assert field(np.array([[0.0, 9.0, 2.0]]))[0] == UNREACHABLE  # past the deviation limit


def test_field_goes_round_a_wall_not_through_it() -> None:
    wall = {"type": "box", "center": [10.0, 0.5, 2.0], "size": [0.5, 5.0, 4.0], "yaw_deg": 0.0}
    world = _world([wall])
    field = cost_field(world, 0.3)
    before = field(np.array([[8.0, 0.0, 2.0]]))[0]
    # the gap is at y < -2: at least the detour's length, well above the straight 11.1 m
    assert before > 12.0 and before < UNREACHABLE


def test_teacher_flies_straight_in_free_space() -> None:
    env = _env(_world([]))
    assert Teacher().labels(env)[0] == FORWARD


@pytest.mark.parametrize("lookahead", [1, 2])
def test_teacher_turns_towards_the_only_gap(lookahead: int) -> None:
    # a wall 2 m ahead from y = -1 to the left edge: only a move to the right (y < 0) avoids it
    wall = {"type": "box", "center": [2.3, 2.0, 2.0], "size": [0.4, 6.0, 4.0], "yaw_deg": 0.0}
    env = _env(_world([wall]))
    teacher = Teacher(TeacherConfig(lookahead=lookahead))
    costs = teacher.action_costs(env)[0]
    best = DEFAULT_DIRECTIONS[int(np.argmin(costs))]
    assert best[1] == -1, best  # a rightward primitive
    assert costs[FORWARD] > costs.min()


def test_a_primitive_into_a_wall_costs_a_crash() -> None:
    # 1 m ahead, from y = -2 to the left edge (the way on is round its right end)
    wall = {"type": "box", "center": [1.0, 1.0, 2.0], "size": [0.4, 6.0, 4.0], "yaw_deg": 0.0}
    env = _env(_world([wall]))
    cfg = TeacherConfig(lookahead=1)
    costs = Teacher(cfg).action_costs(env)[0]
    hover = DEFAULT_DIRECTIONS.index((0, 0, 0))
    assert costs[FORWARD] >= cfg.crash_cost
    assert costs[hover] < cfg.crash_cost


def test_teacher_flies_a_slalom_to_its_goal() -> None:
    panels = [
        {"type": "box", "center": [6.0, 1.5, 2.0], "size": [0.5, 5.0, 4.0], "yaw_deg": 0.0},
        {"type": "box", "center": [12.0, -1.5, 2.0], "size": [0.5, 5.0, 4.0], "yaw_deg": 0.0},
    ]
    env = _env(_world(panels), n=2)
    teacher, outcomes = Teacher(), {}
    for _ in range(60):
        running = np.flatnonzero(~env.done)
        actions = np.zeros(2, dtype=np.int64)
        actions[running] = teacher.labels(env, running)
        info = env.step(actions)[-1]
        outcomes.update({int(i): info["outcome"][i] for i in running if info["outcome"][i] is not None})
        if env.done.all():
            break
    assert outcomes == {0: "goal", 1: "goal"}


def test_soft_targets_rank_as_the_costs_and_sum_to_one() -> None:
    costs = np.array([[3.0, 1.0, 2.0, 100.0]])
    p = soft_targets(costs, 0.5)
    assert np.allclose(p.sum(axis=1), 1.0)
    assert list(np.argsort(-p[0])) == [1, 2, 0, 3]


@pytest.mark.parametrize("kw", [{"grid_m": 0.0}, {"margin_m": float("nan")}, {"lookahead": 3},
                                {"crash_cost": -1.0}, {"setpoint_weight": float("inf")}])
def test_bad_teacher_settings_are_refused_by_name(kw: dict) -> None:
    with pytest.raises(ValueError, match=next(iter(kw))):
        TeacherConfig(**kw)


def test_field_beside_a_wall_cell_is_its_reachable_corners_not_the_wall() -> None:
    """A point between a wall cell and free cells takes the free cells' cost-to-go: a wall corner
    blended in would cost it thousands of metres, a margin a cell wider than the teacher's."""
    from sim_harness.rl.teacher import CostField

    values = np.full((2, 2, 2), 10.0)
    values[1, :, :] = 9.0
    values[1, 1, 1] = UNREACHABLE
    field = CostField(np.zeros(3), 1.0, values)
    got = field(np.array([[0.5, 0.5, 0.5], [0.9, 0.9, 0.9], [0.0, 0.0, 0.0]]))
    # at the centre: 4 corners at 10, 3 at 9 (the wall's weight dropped): 67 / 7
    assert got[0] == pytest.approx(67.0 / 7.0)
    assert 9.0 <= got[1] < 10.0  # next to the wall corner, still the free corners' values
    assert got[2] == pytest.approx(10.0)
    walled = CostField(np.zeros(3), 1.0, np.full((2, 2, 2), UNREACHABLE))
    assert walled(np.array([[0.5, 0.5, 0.5]]))[0] == UNREACHABLE



def test_vetoed_primitives_cost_a_crash_unless_the_filter_vetoes_all() -> None:
    costs = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    allowed = np.array([[False, True, True], [False, False, False]])
    got = vetoed_as_crashes(costs, allowed, 100.0)
    assert got.tolist() == [[101.0, 2.0, 3.0], [1.0, 2.0, 3.0]]
    with pytest.raises(ValueError, match="shape"):
        vetoed_as_crashes(costs[:, :2], allowed, 100.0)


def test_teacher_respecting_the_filter_needs_the_env_to_run_it() -> None:
    with pytest.raises(ValueError, match="filter on"):
        Teacher(TeacherConfig(respect_filter=True)).labels(_env(_world([])))


def test_teacher_respecting_the_filter_takes_its_best_allowed_primitive() -> None:
    # the only-gap wall of the test above, the filter running; its verdicts are then set to veto
    # the teacher's own first and second choices in one env and everything in the other
    wall = {"type": "box", "center": [2.3, 2.0, 2.0], "size": [0.4, 6.0, 4.0], "yaw_deg": 0.0}
    env = VecQuadNavEnv([_world([wall])], 2, seed=0, autoreset=False,
                        config=EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True)))
    env.reset()
    plain, strict = Teacher(), Teacher(TeacherConfig(respect_filter=True))
    costs = plain.action_costs(env, np.arange(2))
    order = np.argsort(costs[0])
    assert np.array_equal(strict.labels(env), plain.labels(env))  # nothing vetoed: the same choice
    env.allowed[:] = True
    env.allowed[0, order[:2]] = False
    env.allowed[1, :] = False
    targets, actions, _ = strict.label(env, None, None, 0.5)
    assert actions[0] == order[2]  # the best of what the filter allows
    assert actions[1] == np.argmin(costs[1])  # all vetoed: the teacher's own choice, as the product flies it
    assert targets[0, order[:2]].max() < targets[0, order[2]]
    assert np.array_equal(strict.labels(env, np.array([0, 1])), actions)


def test_teacher_respecting_the_filter_needs_the_filter_and_the_privileged_teacher() -> None:
    with pytest.raises(ConfigError, match=r"teacher_respect_filter.*shield"):
        load_train_config({"teacher_respect_filter": True}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"teacher_respect_filter.*privileged"):
        load_train_config({"teacher_respect_filter": True, "shield": True, "imitation_teacher": "filter",
                           "init_model": "m.pt"}, "recipe.yaml")
    ok = load_train_config({"teacher_respect_filter": True, "shield": True}, "recipe.yaml")
    assert ok.teacher_respect_filter


def test_teacher_config_carries_every_teacher_key_of_the_training_config() -> None:
    """Each ``teacher_*`` key of TrainConfig, set away from its default, reaches the TeacherConfig
    field of the same name; an override wins over the key."""
    cfg = TrainConfig(
        shield=True, imitation_teacher="privileged", teacher_grid_m=0.5, teacher_margin_m=0.3,
        teacher_lookahead=1, teacher_respect_filter=True, teacher_release_m=0.75,
    )
    keys = [f.name for f in dataclasses.fields(TrainConfig) if f.name.startswith("teacher_")]
    assert len(keys) == 5
    tc = teacher_config(cfg)
    for key in keys:
        assert getattr(tc, key.removeprefix("teacher_")) == getattr(cfg, key) != getattr(TrainConfig(), key)
    lab = teacher_config(cfg, grid_m=0.1, goal_radius_m=0.5)
    assert lab == dataclasses.replace(tc, grid_m=0.1, goal_radius_m=0.5)
