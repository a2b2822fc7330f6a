"""A network that reads the primitive scale it flies at (NetworkConfig.scale_input): its lane, the
widening that adds it, the policy and the daemon's decision passing the scale flown, DAgger's
aggregate keeping each row's scale, and a fit that learns an answer that differs by scale."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
from quadnav_onboard.daemon.decide import Decider
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.observation import ObservationHistory
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.sources.base import DepthFrame
from sim_harness.env import EnvConfig
from sim_harness.rl.agent import AgentConfig, DQNAgent
from sim_harness.rl.config import ConfigError, load_train_config
from sim_harness.rl.evaluate import PolicyGreedy, evaluate, policy_greedy_fn
from sim_harness.rl.imitation import Aggregate, fit
from sim_harness.rl.train import network_config_for
from sim_harness.rl.widen import can_widen, widen
from sim_harness.world import load_world, resolve_world_arg

SCALED = NetworkConfig(depth_history=2, position_history=3, dueling=True, scale_input=True)


def _inputs(n: int, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(n, 2, 32, 32, generator=g), torch.randn(n, 3, 3, generator=g)


def test_the_scale_lane_changes_the_answer_and_is_required() -> None:
    torch.manual_seed(1)
    net = DQN(SCALED)
    depth, rel = _inputs(4)
    half = net(depth, rel, torch.full((4,), 0.5))
    one = net(depth, rel, torch.full((4,), 1.0))
    assert not torch.allclose(half, one)
    with pytest.raises(ValueError, match="scale"):
        net(depth, rel)
    plain = DQN(dataclasses.replace(SCALED, scale_input=False))
    torch.testing.assert_close(plain(depth, rel, torch.full((4,), 0.5)), plain(depth, rel))


def test_the_checkpoint_names_the_lane_only_when_there_is_one(tmp_path) -> None:
    assert "scale_input" not in dataclasses.replace(SCALED, scale_input=False).to_dict()
    assert SCALED.to_dict()["scale_input"] is True
    loaded = load_checkpoint(save_checkpoint(tmp_path / "s.pt", DQN(SCALED)))
    assert loaded.network == SCALED


def test_widening_adds_the_lane_read_at_zero_weight() -> None:
    """The widened network computes exactly what the trained one did, at every scale."""
    torch.manual_seed(2)
    source = DQN(dataclasses.replace(SCALED, scale_input=False, depth_history=1, position_history=2))
    assert can_widen(source.config, SCALED) and not can_widen(SCALED, source.config)
    wide = DQN(SCALED)
    wide.load_state_dict(widen(source, SCALED, seed=3))
    depth, rel = _inputs(5)
    for scale in (0.5, 1.0, 2.0):
        torch.testing.assert_close(wide(depth, rel, torch.full((5,), scale)),
                                   source(depth[:, -1:], rel[:, -2:]), rtol=0, atol=0)
    assert wide.pos_scale[0].weight.abs().sum() > 0  # a fresh lane, so it learns from the first step
    with pytest.raises(ValueError, match="one at a time"):
        widen(source, dataclasses.replace(SCALED, width=2), seed=3)


LOG_RANGE = dataclasses.replace(SCALED, scale_range_m=(0.5, 1.0))


def test_the_log_range_lane_reads_minus_one_and_plus_one_at_the_ends_of_its_range() -> None:
    scales = torch.tensor([0.5, 1.0, 0.5 ** 0.5, 2.0])
    torch.testing.assert_close(LOG_RANGE.scale_feature(scales), torch.tensor([-1.0, 1.0, 0.0, 3.0]))
    torch.testing.assert_close(SCALED.scale_feature(scales), scales)  # without a range: metres
    torch.manual_seed(5)
    net = DQN(LOG_RANGE)
    metres = DQN(SCALED)
    metres.load_state_dict(net.state_dict())  # the same weights: only what the lane reads differs
    depth, rel = _inputs(3)
    assert not torch.allclose(net(depth, rel, 0.5), metres(depth, rel, 0.5))
    with pytest.raises(ValueError, match="scale"):
        net(depth, rel)


@pytest.mark.parametrize("bad", [(1.0, 0.5), (0.5, 0.5), (0.0, 1.0), (0.5, float("nan")), (0.5, 6.0),
                                 (0.5,), "0.5-1.0", (True, 1.0)])
def test_a_bad_scale_range_is_refused_by_name(bad: object) -> None:
    with pytest.raises(ValueError, match=r"scale_range_m must be two scales \(m\) with 0 < lo < hi <= 5"):
        dataclasses.replace(SCALED, scale_range_m=bad)
    with pytest.raises(ValueError, match="needs scale_input: true"):
        NetworkConfig(scale_range_m=(0.5, 1.0))


def test_the_checkpoint_keeps_the_range_and_widening_keeps_it_fixed(tmp_path) -> None:
    assert "scale_range_m" not in SCALED.to_dict()
    assert LOG_RANGE.to_dict()["scale_range_m"] == [0.5, 1.0]
    loaded = load_checkpoint(save_checkpoint(tmp_path / "r.pt", DQN(LOG_RANGE)))
    assert loaded.network == LOG_RANGE and loaded.network.scale_range_m == (0.5, 1.0)
    torch.manual_seed(6)
    source = DQN(dataclasses.replace(SCALED, scale_input=False))
    wide = DQN(LOG_RANGE)
    wide.load_state_dict(widen(source, LOG_RANGE, seed=3))
    depth, rel = _inputs(4)
    for scale in (0.5, 1.0):
        torch.testing.assert_close(wide(depth, rel, scale), source(depth, rel), rtol=0, atol=0)
    # a network that already reads the scale one way is not re-read another way
    assert not can_widen(SCALED, LOG_RANGE) and not can_widen(LOG_RANGE, SCALED)
    assert can_widen(LOG_RANGE, dataclasses.replace(LOG_RANGE, depth_history=3))


def test_the_log_range_encoding_takes_its_range_from_the_scales_trained() -> None:
    keys = {"network_scale_input": True, "imitation_only": True, "dagger_iterations": 1}
    cfg = load_train_config({**keys, "imitation_scales": [1.0, 0.5], "network_scale_encoding": "log-range"},
                            "r.yaml")
    assert network_config_for(cfg).scale_range_m == (0.5, 1.0)
    assert network_config_for(load_train_config({**keys, "imitation_scales": [0.5, 1.0]}, "r.yaml")) \
        .scale_range_m is None
    with pytest.raises(ConfigError, match=r"r\.yaml: key 'network_scale_encoding': .*give two scales"):
        load_train_config({**keys, "imitation_scales": [1.0], "network_scale_encoding": "log-range"},
                          "r.yaml")
    with pytest.raises(ConfigError, match=r"key 'network_scale_encoding': .*set network_scale_input: true"):
        load_train_config({"network_scale_encoding": "log-range"}, "r.yaml")
    with pytest.raises(ConfigError, match=r"key 'network_scale_encoding': bad value 'log'"):
        load_train_config({**keys, "network_scale_encoding": "log"}, "r.yaml")


@pytest.fixture(scope="module")
def scaled_policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    torch.manual_seed(4)
    return Policy.from_path(save_checkpoint(tmp_path_factory.mktemp("m") / "m.pt", DQN(SCALED)))


def test_the_policy_needs_the_scale_flown(scaled_policy: Policy) -> None:
    depth, rel = (t.numpy() for t in _inputs(3))
    assert scaled_policy.reads_scale
    with pytest.raises(ValueError, match="pass scale_m"):
        scaled_policy.q_values_batch(depth, rel)
    for bad in (0.0, float("nan"), -1.0):
        with pytest.raises(ValueError, match=r"finite and > 0 \(m\) in every row"):
            scaled_policy.q_values_batch(depth, rel, bad)
    q = scaled_policy.q_values_batch(depth, rel, 0.5)
    assert not np.allclose(q, scaled_policy.q_values_batch(depth, rel, 1.0))
    action, q0 = scaled_policy.act(depth[0], rel[0], scale_m=0.5)
    np.testing.assert_allclose(q0, q[0], rtol=1e-6, atol=1e-6)
    assert action == int(np.argmax(q[0]))


def test_the_daemon_decides_at_the_scale_of_the_primitives_it_flies(scaled_policy: Policy) -> None:
    rng = np.random.default_rng(5)
    frame = DepthFrame(rng.integers(300, 9000, (240, 424), dtype=np.uint16), 0.0, 0)
    rel = rng.normal(size=3)
    decider = Decider(scaled_policy, PreprocessConfig(), prims=PrimitiveSet(DEFAULT_DIRECTIONS, 0.5, 1.0))
    decision = decider.decide(decider.prepare(frame, decider.snapshot()), rel, "prepared")
    history = ObservationHistory(scaled_policy.depth_history, scaled_policy.position_history)
    history.push(preprocess_depth_mm(frame.depth_mm), rel)
    _, q_half = scaled_policy.act(*history.arrays(), scale_m=0.5)
    _, q_one = scaled_policy.act(*history.arrays(), scale_m=1.0)
    np.testing.assert_array_equal(decision.q, q_half)
    assert not np.allclose(decision.q, q_one)


def test_evaluate_hands_each_world_its_scale(scaled_policy: Policy) -> None:
    """The eval's greedy policy is told the env's scale; called without it, the model refuses."""
    world = load_world(resolve_world_arg("env01"))
    seen: list[float | None] = []

    class Spy(PolicyGreedy):
        def at_scale(self, scale_m: float) -> PolicyGreedy:
            seen.append(scale_m)
            return super().at_scale(scale_m)

    env_cfg = EnvConfig(max_steps=3, depth_history=2, position_history=3)
    half = dataclasses.replace(env_cfg, primitives=dataclasses.replace(env_cfg.primitives, scale_m=0.5))
    evaluate(Spy(scaled_policy), [world], 2, 0, half)
    evaluate(Spy(scaled_policy), [world], 2, 0, env_cfg)
    assert seen == [0.5, 1.0]
    with pytest.raises(ValueError, match="pass scale_m"):
        policy_greedy_fn(scaled_policy)(*(t.numpy() for t in _inputs(2)), np.ones((2, 18), bool))


def _conflicting_labels(n: int) -> Aggregate:
    """The same observations labelled primitive 4 at 0.5 m and primitive 1 at 1 m (the corridor's
    sideways step: right at one scale, a crash at the other)."""
    depth, rel = (t.numpy() for t in _inputs(n, seed=7))
    data = Aggregate(4 * n, (2, 32, 32), (3, 3), 18)
    for scale, action in ((0.5, 4), (1.0, 1)):
        target = np.zeros((n, 18), np.float32)
        target[:, action] = 1.0
        data.add(depth, rel, target, 0, scale_m=scale)
    return data


@pytest.mark.parametrize("reads_scale", [True, False])
def test_a_fit_learns_an_answer_that_differs_by_scale_only_with_the_lane(reads_scale: bool) -> None:
    torch.manual_seed(8)
    data = _conflicting_labels(64)
    np.testing.assert_array_equal(np.unique(data.scale_m[: len(data)]), [0.5, 1.0])
    unscaled = Aggregate(8, (2, 32, 32), (3, 3), 18)
    unscaled.add(data.depth[:8], data.rel[:8], data.target[:8], 0)  # no scale said: NaN, refused below
    student = DQNAgent(SCALED)
    with pytest.raises(ValueError, match=r"finite and > 0 \(m\) in every row"):
        fit(student, unscaled, epochs=1.0, batch_size=8, rng=np.random.default_rng(0),
            optimizer=student.optimizer)
    agent = DQNAgent(dataclasses.replace(SCALED, scale_input=reads_scale), AgentConfig(learning_rate=1e-3))
    fit(agent, data, epochs=160.0, batch_size=64, rng=np.random.default_rng(9), optimizer=agent.optimizer)
    depth, rel = data.depth[:64].astype(np.float32), data.rel[:64]
    half = agent.greedy(depth, rel, scale_m=0.5)
    one = agent.greedy(depth, rel, scale_m=1.0)
    if reads_scale:
        assert (half == 4).mean() > 0.95 and (one == 1).mean() > 0.95
    else:  # one answer for both scales: at least one of them is wrong nearly everywhere
        np.testing.assert_array_equal(half, one)
        assert min((half == 4).mean(), (one == 1).mean()) < 0.05


def test_the_config_keeps_the_lane_to_imitation() -> None:
    with pytest.raises(ConfigError, match=r"r\.yaml: key 'network_scale_input'"):
        load_train_config({"network_scale_input": True}, "r.yaml")
    cfg = load_train_config({"network_scale_input": True, "imitation_only": True, "dagger_iterations": 1},
                            "r.yaml")
    assert cfg.network_scale_input


def test_dagger_keeps_the_scale_each_state_was_flown_at_and_tells_the_student() -> None:
    """collect() stores its env's primitive scale with every row and flies the student told it."""
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.rl.imitation import collect
    from sim_harness.rl.teacher import Teacher, TeacherConfig

    told: list[float | None] = []

    class Student(DQNAgent):
        def greedy(self, depth, rel, allowed=None, scale_m=None):
            told.append(scale_m)
            return super().greedy(depth, rel, allowed, scale_m)

    world = load_world(resolve_world_arg("env01"))
    base = EnvConfig(max_steps=4, depth_history=2, position_history=3)
    cfg = dataclasses.replace(base, primitives=dataclasses.replace(base.primitives, scale_m=0.5))
    env = VecQuadNavEnv([world], 2, seed=0, config=cfg)
    env.reset()
    data = Aggregate(100, (2, 32, 32), (3, 3), 18)
    collect(env, Teacher(TeacherConfig()), Student(SCALED), 2, 0.0, np.random.default_rng(0), 0.3, data, 0)
    assert len(data) > 0 and set(data.scale_m[: len(data)].tolist()) == {0.5}
    assert told and set(told) == {0.5}


def test_the_filter_teacher_tells_an_expert_that_reads_the_scale_the_scale_flown() -> None:
    from sim_harness.rl.filter_teacher import FilterTeacher

    torch.manual_seed(10)
    teacher = FilterTeacher(DQN(SCALED))
    depth, rel = (t.numpy() for t in _inputs(3))
    assert not np.allclose(teacher.q_values(depth, rel, 0.5), teacher.q_values(depth, rel, 1.0))
    with pytest.raises(ValueError, match="pass scale_m"):
        teacher.q_values(depth, rel)
