"""The filter as a teacher: its labels are the product's choices, and a student learns them."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint
from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.policy import masked_argmax
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent
from sim_harness.rl.config import TrainConfig, load_train_config
from sim_harness.rl.filter_teacher import FilterTeacher, veto_targets
from sim_harness.rl.imitation import Aggregate, collect, fit, veto_loss
from sim_harness.rl.train import train
from sim_harness.world import parse_world

FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_veto_targets_put_every_vetoed_primitive_below_the_allowed_ones() -> None:
    rng = np.random.default_rng(0)
    q = rng.normal(size=(200, 18)).astype(np.float32)
    allowed = rng.random((200, 18)) < 0.6
    allowed[0] = False  # nothing allowed: the filter flies the arg-max of all, the label says so
    allowed[1] = True
    t = veto_targets(q, allowed, 0.5)
    np.testing.assert_array_equal(np.argmax(t, axis=1), masked_argmax(q, allowed))
    np.testing.assert_array_equal(t[allowed], q[allowed])  # the expert's values where allowed
    np.testing.assert_array_equal(t[0], q[0])
    for row in range(2, 200):
        if allowed[row].any() and not allowed[row].all():
            assert t[row][~allowed[row]].max() == pytest.approx(q[row][allowed[row]].min() - 0.5)
    with pytest.raises(ValueError, match="shape"):
        veto_targets(q, allowed[:, :3], 0.5)
    with pytest.raises(ValueError, match="margin"):
        veto_targets(q, allowed, 0.0)


def _wall_world(wall_x: float):
    return parse_world({
        "name": "wall",
        "path": {"waypoints": [[0.0, 0.0, 2.0], [8.0, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": [{"type": "box", "center": [wall_x, 0.0, 2.0], "size": [0.2, 6.0, 4.0]}],
    })


def test_the_label_is_the_forward_expert_unless_the_filter_vetoes_forward(tmp_path) -> None:
    """An expert that always prefers forward: far from a wall its label is forward; with a wall
    1 m ahead the filter vetoes forward, and the label is the filter's choice instead."""
    expert = constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD).model
    teacher = FilterTeacher(expert, veto_margin=1.0)
    cfg = EnvConfig(max_steps=5, start_jitter_m=0.0, shield=ShieldConfig(enabled=True))
    for wall_x, forward_ok in ((7.5, True), (1.1, False)):
        env = VecQuadNavEnv([_wall_world(wall_x)], 2, seed=0, config=cfg)
        depth, rel = env.reset()
        target, actions, released = teacher.label(env, depth, rel, 0.1)
        assert bool(env.allowed[:, FORWARD].all()) is forward_ok
        np.testing.assert_array_equal(np.argmax(target, axis=1), actions)
        assert bool(np.all(actions == FORWARD)) is forward_ok
        assert np.all(env.allowed[np.arange(2), actions])
        assert not released.any()  # the filter teacher's labels are its verdicts


def test_the_filter_teacher_needs_the_envs_filter(tmp_path) -> None:
    expert = constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD).model
    env = VecQuadNavEnv([_wall_world(7.5)], 1, seed=0, config=EnvConfig(max_steps=5))
    depth, rel = env.reset()
    with pytest.raises(ValueError, match="filter"):
        FilterTeacher(expert).label(env, depth, rel, 0.1)


def test_collect_with_the_filter_teacher_labels_every_state_the_expert_flew(tmp_path) -> None:
    expert = constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD).model
    teacher = FilterTeacher(expert)
    cfg = EnvConfig(max_steps=8, shield=ShieldConfig(enabled=True))
    env = VecQuadNavEnv([_wall_world(4.0)], 2, seed=0, config=cfg)
    env.reset()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    counts = collect(env, teacher, DQNAgent(NetworkConfig()), 2, 1.0, np.random.default_rng(0), 0.1, data, 0)
    assert sum(counts.values()) == 2 and "crash" not in counts  # the filter kept it off the wall
    labels = np.argmax(data.target[: len(data)], axis=1)
    assert (labels == FORWARD).any() and (labels != FORWARD).any()  # forward, then round the wall
    kept = data.allowed[: len(data)]  # the filter's verdicts, kept with the labels
    assert not kept[labels != FORWARD, FORWARD].any()  # where forward was vetoed
    assert kept[np.arange(len(data)), labels].all()  # the label's first choice was allowed


def test_huber_fit_learns_q_labels(side_rule) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    agent = DQNAgent(NetworkConfig())
    data = Aggregate(256, (1, 32, 32), (1, 3), 18)
    depth, rel, left = side_rule(rng, 256)
    best = np.where(left, FORWARD, 0)
    target = np.zeros((256, 18), np.float32)
    target[np.arange(256), best] = 2.0
    data.add(depth, rel, target, 0)
    opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
    _, agreement = fit(agent, data, 40.0, 64, rng, opt, "huber")
    assert np.mean(agent.greedy(depth, rel) == best) > 0.95 and agreement > 0.9
    with torch.no_grad():
        q = agent.q(torch.as_tensor(depth), torch.as_tensor(rel)).numpy()
    assert np.abs(q - target).mean() < 0.2  # values, not only the order
    with pytest.raises(ValueError, match="loss_kind"):
        fit(agent, data, 1.0, 64, rng, torch.optim.Adam(agent.q.parameters()), "mse")


def test_the_filter_teacher_needs_an_expert_and_the_filter_in_the_config() -> None:
    base = {"dagger_iterations": 1, "imitation_teacher": "filter"}
    with pytest.raises(ConfigError, match=r"imitation_teacher.*init_model"):
        load_train_config({**base, "shield": True}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"imitation_teacher.*shield"):
        load_train_config({**base, "init_model": "m.pt"}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"imitation_teacher.*'oracle'"):
        load_train_config({"imitation_teacher": "oracle"}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"dagger_filtered_share.*0\.5.*shield"):
        load_train_config({"dagger_filtered_share": 0.5}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"imitation_veto_weight.*2\.0.*shield"):
        load_train_config({"imitation_veto_weight": 2.0}, "recipe.yaml")
    ok = load_train_config({**base, "shield": True, "init_model": "m.pt"}, "recipe.yaml")
    assert ok.imitation_teacher == "filter"


def test_train_with_the_filter_teacher_starts_from_the_expert_and_writes_a_model(tmp_path) -> None:
    expert_path = tmp_path / "fwd.pt"
    constant_action_checkpoint(str(expert_path), FORWARD, NetworkConfig(depth_history=1, position_history=1))
    cfg = TrainConfig(
        name="fd", seed=1, train_worlds=(1,), n_envs=4, max_steps=10, batch_size=16, shield=True,
        init_model=str(expert_path), imitation_teacher="filter", dagger_iterations=2, dagger_episodes=2,
        imitation_scales=(1.0,), imitation_only=True, imitation_epochs=1.0, out_dir=str(tmp_path),
    )
    result = train(cfg, progress=False)
    records = json.loads((result.run_dir / "dagger.json").read_text())
    assert [r["iteration"] for r in records] == [0, 1]
    # Env 1 is free: the filter never vetoes forward, so the student stays the forward expert
    assert records[-1]["agreement"] == pytest.approx(1.0)
    ck = load_checkpoint(result.model_path)
    assert ck.meta["train_config"]["imitation_teacher"] == "filter" and ck.meta["shield"]["enabled"]


def test_dagger_can_fly_the_student_behind_the_filter(tmp_path) -> None:
    """``filtered_share``: a forward-only student flown alone hits the wall; behind the filter (as
    the product flies it) it does not, and both flights' states are labelled."""
    fwd = constant_action_checkpoint(str(tmp_path / "fwd.pt"), FORWARD).model
    student = DQNAgent(NetworkConfig())
    student.q.load_state_dict(fwd.state_dict())
    cfg = EnvConfig(max_steps=8, start_jitter_m=0.0, shield=ShieldConfig(enabled=True))
    outcomes = {}
    for share in (0.0, 1.0):
        env = VecQuadNavEnv([_wall_world(3.0)], 2, seed=0, config=cfg)
        env.reset()
        data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
        outcomes[share] = collect(env, FilterTeacher(fwd), student, 2, 0.0, np.random.default_rng(0), 0.1,
                                  data, 1, filtered_share=share)
        assert len(data) > 0
    assert outcomes[0.0].get("crash", 0) == 2
    assert "crash" not in outcomes[1.0]


def test_veto_loss_is_zero_only_where_an_allowed_primitive_leads_every_vetoed_one() -> None:
    q = torch.tensor([[3.0, 1.0, 0.0],    # allowed 0 and 2, vetoed 1: 3 leads 1 by 2 >= 1
                      [3.0, 2.5, 0.0],    # the same verdicts, a lead of 0.5: 1 + 2.5 - 3
                      [1.0, 2.0, 3.0],    # all allowed: no hinge
                      [1.0, 2.0, 3.0]])   # only 0 allowed: 1 + 3 - 1
    allowed = torch.tensor([[1, 0, 1], [1, 0, 1], [1, 1, 1], [1, 0, 0]], dtype=torch.bool)
    assert float(veto_loss(q, allowed, 1.0)) == pytest.approx((0.0 + 0.5 + 0.0 + 3.0) / 4)
    none_vetoed = torch.ones_like(allowed)
    assert float(veto_loss(q, none_vetoed, 1.0)) == 0.0


def test_the_veto_hinge_makes_the_students_first_choice_one_the_filter_allows(side_rule) -> None:
    """Q labels that rank a vetoed primitive first by a hair (as a label from a wrong expert
    would): the Huber fit alone copies that order; with the hinge, the student's first choice is
    an allowed primitive."""
    rng = np.random.default_rng(0)
    n = 256
    depth, rel, left = side_rule(rng, n)
    vetoed = np.where(left, FORWARD, 0)
    target = np.ones((n, 18), np.float32)
    target[np.arange(n), vetoed] = 1.05
    allowed = np.ones((n, 18), bool)
    allowed[np.arange(n), vetoed] = False
    data = Aggregate(n, (1, 32, 32), (1, 3), 18)
    data.add(depth, rel, target, 0, allowed)
    first_allowed = {}
    for weight in (0.0, 1.0):
        torch.manual_seed(0)
        agent = DQNAgent(NetworkConfig())
        opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
        fit(agent, data, 30.0, 64, np.random.default_rng(0), opt, "huber", veto_weight=weight, margin=0.5)
        first_allowed[weight] = np.mean(allowed[np.arange(n), agent.greedy(depth, rel)])
    assert first_allowed[1.0] > 0.95
    assert first_allowed[0.0] < 0.5
