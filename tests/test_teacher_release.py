"""The teacher that respects the filter, released where the filter boxes it in
(``teacher_release_m``): there it chooses among every primitive. That those labels carry no
verdicts into DAgger's aggregate is tested with the other verdict tests
(tests/test_imitation_filter_scales.py)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.config import ConfigError, load_train_config
from sim_harness.rl.teacher import Teacher, TeacherConfig, released_by
from sim_harness.world import load_world

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _filtered_env(world_file: Path, n: int) -> VecQuadNavEnv:
    """``n`` envs of ``world_file`` with the filter on, all at its start."""
    world = load_world(world_file)
    env = VecQuadNavEnv([world], n, seed=0, autoreset=False,
                        config=EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True)))
    env.reset()
    return env


def test_released_where_the_vetoes_cost_more_than_the_threshold() -> None:
    costs = np.array([[1.0, 2.0, 3.0], [1.0, 1.2, 3.0], [1.0, 2.0, 3.0]])
    chosen = costs + np.array([[100.0, 100.0, 0.0], [100.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert released_by(costs, chosen, 0.5).tolist() == [True, False, False]
    assert released_by(costs, chosen, 2.5).tolist() == [False, False, False]


def test_the_teacher_leaves_the_filter_aside_only_where_it_boxes_it_in(tmp_path: Path,
                                                                       straight_world) -> None:
    env = _filtered_env(straight_world(tmp_path, 20.0, height_m=2.0), 2)  # a free 20 m path at 2 m
    plain = Teacher()
    costs = plain.action_costs(env, np.arange(2))
    np.testing.assert_allclose(costs[0], costs[1])  # one state twice: one ranking serves both
    order = np.argsort(costs[0])
    # env 0: the filter allows only the teacher's worst primitive; env 1: all but its best
    env.allowed[:] = True
    env.allowed[0, :] = False
    env.allowed[0, order[-1]] = True
    env.allowed[1, order[0]] = False
    boxed_in = costs[0, order[-1]] - costs[0, order[0]]
    detour = costs[1, order[1]] - costs[1, order[0]]
    assert boxed_in > 2 * detour  # the two kinds of state the threshold tells apart
    release = (boxed_in + detour) / 2
    strict = Teacher(TeacherConfig(respect_filter=True))
    released = Teacher(TeacherConfig(respect_filter=True, release_m=release))

    kept = strict.label(env, None, None, 0.3)
    got = released.label(env, None, None, 0.3)
    assert kept.released.tolist() == [False, False]
    assert kept.actions.tolist() == [order[-1], order[1]]
    assert got.released.tolist() == [True, False]
    assert got.actions.tolist() == [order[0], order[1]]  # boxed in: the teacher's own best
    np.testing.assert_allclose(got.targets[1], kept.targets[1])  # a detour: as before
    assert np.array_equal(released.labels(env), got.actions)


def test_the_release_needs_a_teacher_that_respects_the_filter() -> None:
    with pytest.raises(ConfigError, match=r"recipe.yaml: key 'teacher_release_m': bad value 0.75.*respect"):
        load_train_config({"shield": True, "teacher_release_m": 0.75}, "recipe.yaml")
    ok = load_train_config({"shield": True, "teacher_respect_filter": True, "teacher_release_m": 0.75},
                           "recipe.yaml")
    assert ok.teacher_release_m == 0.75
    with pytest.raises(ValueError, match="release_m"):
        TeacherConfig(release_m=float("nan"))
