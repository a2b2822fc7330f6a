"""Stable-Baselines3 on the navigation env: the paper's network as SB3's Q-network, the batched
VecEnv's SB3 conventions, and a tiny DQN run that trains and is evaluated."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
import torch

pytest.importorskip("stable_baselines3", reason='the sb3 extra is not installed (pip install "quadnav[sb3]")')

from quadnav_onboard.network import DQN, count_parameters
from sim_harness.env import EnvConfig, observation_space
from sim_harness.rl.evaluate import evaluate, summarize
from sim_harness.sb3 import PaperLanes, QuadNavSB3VecEnv, greedy_fn, train_dqn
from sim_harness.world import load_world, paper_world_path, parse_world


@pytest.fixture(autouse=True)
def _restore_threads():
    before = torch.get_num_threads()
    yield
    torch.set_num_threads(before)


def _wall_world():
    return parse_world(
        {
            "name": "wall",
            "path": {"waypoints": [[0, 0, 2], [30, 0, 2]]},
            "obstacles": [{"type": "box", "center": [3.0, 0, 2], "size": [0.2, 20, 20]}],
        },
        "test",
    )


def test_the_extractor_is_the_papers_lanes_and_the_q_network_has_the_papers_size() -> None:
    worlds = [load_world(paper_world_path(1))]
    model = train_dqn(worlds, timesteps=32, n_envs=4, learning_starts=10_000, buffer_size=100)
    assert isinstance(model.q_net.features_extractor, PaperLanes)
    assert count_parameters(model.q_net) == count_parameters(DQN()) == 73_946


def test_the_extractor_with_the_papers_trunk_computes_the_papers_q_values() -> None:
    """Lanes and trunk copied from a DQN: SB3's layout gives the same Q-values for the same input."""
    torch.manual_seed(0)
    paper = DQN()
    lanes = PaperLanes(observation_space([load_world(paper_world_path(1))], EnvConfig()))
    lanes.load_state_dict({k: v for k, v in paper.state_dict().items() if not k.startswith(("trunk", "out"))})
    depth, rel = torch.rand(5, 1, 32, 32), torch.randn(5, 1, 3)
    head = torch.nn.Sequential(paper.trunk, paper.out)
    got = head(lanes({"depth": depth, "rel_pos": rel}))
    assert torch.allclose(got, paper(depth, rel))


def test_the_vec_env_reports_the_terminal_observation_and_the_episode_as_sb3_expects() -> None:
    venv = QuadNavSB3VecEnv([_wall_world()], 2, seed=0, config=EnvConfig(start_jitter_m=0.0))
    obs = venv.reset()
    total, steps = np.zeros(2), 0
    for _ in range(10):
        venv.step_async(np.full(2, 4))  # straight ahead into the wall
        obs, rew, done, infos = venv.step_wait()
        total += rew
        steps += 1
        if done.any():
            break
    assert done.all() and (rew < 0).all()
    for i, info in enumerate(infos):
        assert info["outcome"] == "crash" and info["TimeLimit.truncated"] is False
        assert info["episode"]["l"] == steps and info["episode"]["r"] == pytest.approx(total[i], abs=1e-5)
        assert not np.array_equal(info["terminal_observation"]["rel_pos"], obs["rel_pos"][i])
    assert venv.vec.steps.tolist() == [0, 0]  # started anew in the same step


def test_sb3_dqn_trains_on_the_env_and_its_greedy_policy_is_evaluated(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tiny budget: updates happen (the weights move), the greedy policy flies the evaluation,
    and training leaves no ``SB3-<time>`` folder in the temporary directory (SB3's default
    logger makes one on every learn())."""
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    monkeypatch.delenv("SB3_LOGDIR", raising=False)
    worlds = [load_world(paper_world_path(i)) for i in (1, 2)]
    model = train_dqn(worlds, timesteps=600, n_envs=8, learning_starts=200, buffer_size=2_000, seed=1)
    assert not list(tmp_path.glob("SB3-*"))
    assert model.num_timesteps >= 600 and model._n_updates > 0
    rows = evaluate(greedy_fn(model), worlds, 2, seed=1000)
    summary = summarize(rows)
    assert summary["trials"] == 4 and {r.outcome for r in rows} <= {"goal", "crash", "deviation", "timeout"}
    assert all(r.time_s > 0 for r in rows)
