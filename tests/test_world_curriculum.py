"""DAgger's failure-weighted world sampling: the worlds the student fails in are flown more."""

from __future__ import annotations

import json

import numpy as np
import pytest

from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent
from sim_harness.rl.config import TrainConfig, load_train_config
from sim_harness.rl.filter_teacher import FilterTeacher
from sim_harness.rl.imitation import Aggregate, WorldCurriculum, collect
from sim_harness.rl.train import train
from sim_harness.world import parse_world

FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _world(name: str, wall: bool):
    obstacles = [{"type": "box", "center": [3.0, 0.0, 2.0], "size": [0.2, 6.0, 4.0]}] if wall else []
    return parse_world({
        "name": name,
        "path": {"waypoints": [[0.0, 0.0, 2.0], [8.0, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": obstacles,
    })


def test_weights_are_the_floor_plus_the_recent_failure_rate() -> None:
    c = WorldCurriculum(3, floor=0.1)
    for _ in range(4):
        c.record(0, "goal")
        c.record(1, "crash")
    # world 2 never flown: half failed; (failures + 0.5) / (episodes + 1) for the others
    np.testing.assert_allclose(c.next_weights(), [0.1 + 0.5 / 5, 0.1 + 4.5 / 5, 0.1 + 0.5])
    # the counts so far now weigh half: four goals in world 1 do not yet outweigh its past crashes
    for _ in range(4):
        c.record(1, "goal")
    np.testing.assert_allclose(c.failure_rate()[1], (2 + 0.5) / (6 + 1))
    with pytest.raises(ValueError, match="floor"):
        WorldCurriculum(2, floor=0.0)


def test_the_env_picks_worlds_by_the_weights_and_refuses_bad_ones() -> None:
    env = VecQuadNavEnv([_world("a", False), _world("b", False)], 64, seed=0)
    env.set_world_weights([0.0, 1.0])
    env.reset()
    assert np.all(env.world_idx == 1)
    for bad in ([1.0], [1.0, np.nan], [-1.0, 2.0], [0.0, 0.0]):
        with pytest.raises(ValueError, match="world weights"):
            env.set_world_weights(bad)


def test_a_student_that_crashes_in_one_world_is_sent_there_more_often(tmp_path) -> None:
    fwd = constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD).model
    student = DQNAgent(NetworkConfig())
    student.q.load_state_dict(fwd.state_dict())  # flies straight on: the goal in "open", a crash in "wall"
    env = VecQuadNavEnv([_world("open", False), _world("wall", True)], 4, seed=0,
                        config=EnvConfig(max_steps=12, start_jitter_m=0.0, shield=ShieldConfig(enabled=True)))
    env.reset()
    teacher, rng = FilterTeacher(fwd), np.random.default_rng(0)
    data = Aggregate(20_000, (1, 32, 32), (1, 3), 18)
    curriculum = WorldCurriculum(2, floor=0.1)
    first = collect(env, teacher, student, 20, 0.0, rng, 0.1, data, 1, curriculum=curriculum)
    assert first.get("goal", 0) > 0 and first.get("crash", 0) > 0
    weights = curriculum.next_weights()
    assert weights[1] > 3 * weights[0]
    env.set_world_weights(weights)
    seen = WorldCurriculum(2, floor=0.1)
    collect(env, teacher, student, 40, 0.0, rng, 0.1, data, 2, curriculum=seen)
    picked = [int(e) for e in seen.episodes]
    # uniform sampling would fly each about 20 times; the crashing world gets most episodes
    assert picked[1] > 2 * picked[0], picked


def test_training_with_the_curriculum_records_each_iterations_weights(tmp_path) -> None:
    constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD, NetworkConfig())
    cfg = TrainConfig(
        name="cur", seed=1, train_worlds=(1, 2), n_envs=4, max_steps=10, batch_size=16, shield=True,
        init_model=str(tmp_path / "fwd.pt"), imitation_teacher="filter", dagger_iterations=2,
        dagger_episodes=2, imitation_scales=(1.0,), imitation_only=True, imitation_epochs=1.0,
        dagger_world_sampling="failures", dagger_world_floor=0.2, out_dir=str(tmp_path),
    )
    records = json.loads((train(cfg, progress=False).run_dir / "dagger.json").read_text())
    assert [r["iteration"] for r in records] == [0, 1]
    for r in records:
        assert len(r["world_weights"]) == 2 and all(0.2 < w <= 1.2 for w in r["world_weights"])
    with pytest.raises(ConfigError, match=r"dagger_world_sampling.*'hardest'"):
        load_train_config({"dagger_world_sampling": "hardest"}, "recipe.yaml")
