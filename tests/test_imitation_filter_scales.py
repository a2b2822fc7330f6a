"""The filter's lessons at some scales only (``imitation_filter_scales``): elsewhere the teacher
plans on the true world alone and the hinge sees no verdicts."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quadnav_onboard.config import ConfigError
from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent
from sim_harness.rl.config import load_train_config
from sim_harness.rl.imitation import Aggregate, collect
from sim_harness.rl.teacher import Teacher
from sim_harness.rl.train import dagger_tasks, env_config_for
from sim_harness.world import parse_world

pytestmark = pytest.mark.usefixtures("one_torch_thread")

RECIPE = {
    "imitation_teacher": "privileged", "shield": True, "teacher_respect_filter": True,
    "imitation_veto_weight": 3.0, "dagger_iterations": 1, "imitation_scales": [1.0, 0.5],
}


def _wall_world():
    """A panel 2.5 m ahead, with room round it: the filter vetoes some primitives near it."""
    return parse_world({
        "name": "panel",
        "path": {"waypoints": [[0.0, 0.0, 2.0], [8.0, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": [{"type": "box", "center": [2.5, 0.0, 2.0], "size": [0.2, 1.0, 1.0]}],
    })


def _tasks(**keys):
    cfg = load_train_config({**RECIPE, **keys}, "recipe.yaml")
    return dagger_tasks(cfg, env_config_for(cfg), [_wall_world()])


def test_outside_the_filter_scales_the_teacher_ignores_the_filter_and_no_verdicts_are_kept() -> None:
    by_scale = {t.config.primitives.scale_m: t for t in _tasks(imitation_filter_scales=[0.5])}
    assert by_scale[0.5].teacher.config.respect_filter and by_scale[0.5].filter_verdicts
    assert not by_scale[1.0].teacher.config.respect_filter and not by_scale[1.0].filter_verdicts
    # the rest of the teacher is the recipe's at both scales
    free, kept = by_scale[1.0].teacher.config, by_scale[0.5].teacher.config
    assert free == dataclasses.replace(kept, respect_filter=False)


def test_without_filter_scales_every_scale_learns_the_filters_lessons() -> None:
    tasks = _tasks()
    assert [t.config.primitives.scale_m for t in tasks] == [1.0, 0.5]
    assert all(t.teacher.config.respect_filter and t.filter_verdicts for t in tasks)


def test_a_filter_scale_must_be_one_of_the_imitation_scales() -> None:
    with pytest.raises(ConfigError, match=r"recipe.yaml: key 'imitation_filter_scales'.*0\.25"):
        load_train_config({**RECIPE, "imitation_filter_scales": [0.25]}, "recipe.yaml")


def test_filter_scales_need_the_privileged_teacher() -> None:
    """The filter teacher's labels are the filter's verdicts: it cannot leave the filter out."""
    filter_recipe = {**RECIPE, "imitation_teacher": "filter", "teacher_respect_filter": False,
                     "init_model": "quadnav_onboard/models/pgud.pt"}
    load_train_config(filter_recipe, "recipe.yaml")  # without the key: a valid recipe
    with pytest.raises(ConfigError, match=r"recipe.yaml: key 'imitation_filter_scales'.*privileged"):
        load_train_config({**filter_recipe, "imitation_filter_scales": [0.5]}, "recipe.yaml")


@pytest.mark.parametrize("keep", [True, False])
def test_collect_keeps_the_verdicts_only_when_asked(keep: bool) -> None:
    cfg = EnvConfig(max_steps=6, start_jitter_m=0.0, shield=ShieldConfig(enabled=True))
    env = VecQuadNavEnv([_wall_world()], 2, seed=0, config=cfg)
    env.reset()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    seen = []
    real_add = data.add

    def add(depth, rel, target, iteration, allowed=None):
        seen.append(np.array(env.allowed))  # what the filter said in that state
        real_add(depth, rel, target, iteration, allowed)

    data.add = add  # type: ignore[method-assign]
    collect(env, Teacher(), DQNAgent(NetworkConfig()), 2, 1.0, np.random.default_rng(0), 0.1, data, 0,
            keep_verdicts=keep)
    said = np.concatenate(seen)
    assert not said.all()  # the filter vetoed something on the way past the panel
    kept = data.allowed[: len(data)]
    if keep:
        np.testing.assert_array_equal(kept, said)
    else:
        assert kept.all()  # every primitive counts as allowed: the hinge has nothing to learn
