"""Which labels carry the filter's lessons: at some scales only (``imitation_filter_scales``;
elsewhere the teacher plans on the true world alone and the hinge sees no verdicts), and not in
the states where the teacher was released from the filter (``teacher_release_m``)."""

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
from sim_harness.rl.imitation import Aggregate, DaggerSettings, DaggerTask, Labels, collect, dagger
from sim_harness.rl.teacher import Teacher, TeacherConfig
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


def collect_by_the_panel(teacher, keep: bool = True) -> tuple[Aggregate, np.ndarray]:
    """Two episodes past the panel of :func:`_wall_world`, the teacher flying: DAgger's aggregate,
    and what the filter said in each state it holds (rows in the same order)."""
    cfg = EnvConfig(max_steps=6, start_jitter_m=0.0, shield=ShieldConfig(enabled=True))
    env = VecQuadNavEnv([_wall_world()], 2, seed=0, config=cfg)
    env.reset()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    seen = []
    real_add = data.add

    def add(depth, rel, target, iteration, allowed=None, released=None, scale_m=None):
        seen.append(np.array(env.allowed))  # what the filter said in that state
        real_add(depth, rel, target, iteration, allowed, released, scale_m)

    data.add = add  # type: ignore[method-assign]
    collect(env, teacher, DQNAgent(NetworkConfig()), 2, 1.0, np.random.default_rng(0), 0.1, data, 0,
            keep_verdicts=keep)
    return data, np.concatenate(seen)


@pytest.mark.parametrize("keep", [True, False])
def test_collect_keeps_the_verdicts_only_when_asked(keep: bool) -> None:
    data, said = collect_by_the_panel(Teacher(), keep)
    assert not said.all()  # the filter vetoed something on the way past the panel
    kept = data.allowed[: len(data)]
    if keep:
        np.testing.assert_array_equal(kept, said)
    else:
        assert kept.all()  # every primitive counts as allowed: the hinge has nothing to learn


class _HalfReleased:
    """The privileged teacher respecting the filter, its labels marked released in env 0 and
    kept in env 1 (``teacher_release_m`` decides this by the costs; here it is fixed)."""

    loss = "cross_entropy"

    def __init__(self) -> None:
        self.teacher = Teacher(TeacherConfig(respect_filter=True))

    def label(self, env, depth, rel, temperature_m) -> Labels:
        targets, actions, _ = self.teacher.label(env, depth, rel, temperature_m)
        return Labels(targets, actions, np.array([True, False]))


def test_a_released_label_keeps_no_verdict_and_the_others_keep_theirs() -> None:
    data, said = collect_by_the_panel(_HalfReleased())
    n = len(data)
    in_env0 = np.arange(n) % 2 == 0  # each step adds env 0's state, then env 1's
    assert not said[~in_env0].all()  # the filter vetoed something in env 1's states
    assert data.allowed[:n][in_env0].all()  # released: no verdict
    np.testing.assert_array_equal(data.allowed[:n][~in_env0], said[~in_env0])
    assert data.released[:n].tolist() == in_env0.tolist()


class _AllReleased(_HalfReleased):
    """As :class:`_HalfReleased`, every label marked released."""

    def label(self, env, depth, rel, temperature_m) -> Labels:
        targets, actions, _ = self.teacher.label(env, depth, rel, temperature_m)
        return Labels(targets, actions, np.ones(env.n_envs, dtype=bool))


def test_dagger_counts_each_task_s_released_labels_past_the_aggregate_s_ring() -> None:
    """Each record counts the states its task labelled in its iteration and the released ones
    among them, kept when the aggregate's ring has overwritten them (its ``released`` column
    alone cannot split the count between tasks, nor keep it)."""
    cfg = EnvConfig(max_steps=6, start_jitter_m=0.0, shield=ShieldConfig(enabled=True))
    tasks = [DaggerTask(cfg, [_wall_world()], _AllReleased()),
             DaggerTask(cfg, [_wall_world()], Teacher(TeacherConfig(respect_filter=True)))]
    settings = DaggerSettings(iterations=2, episodes=2, beta=1.0, epochs=0.1, lr=1e-3, temperature_m=0.1,
                              batch_size=4, buffer=16, seed=0)
    records = dagger(DQNAgent(NetworkConfig()), tasks, settings, n_envs=2)
    assert [r["iteration"] for r in records] == [0, 0, 1, 1]
    released_task, kept_task = records[0::2], records[1::2]
    assert all(r["labelled"] >= 2 for r in records)  # two envs, at least one step each
    assert all(r["labelled_released"] == r["labelled"] for r in released_task)
    assert all(r["labelled_released"] == 0 for r in kept_task)
    assert sum(r["labelled"] for r in records) > settings.buffer  # the ring has overwritten rows
    assert records[-1]["dataset"] == settings.buffer
    assert records[-1]["released"] < sum(r["labelled_released"] for r in released_task)
