"""A trained network widened to a longer input history, or to wider layers, computes what it did,
and can learn more."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from quadnav_onboard.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from quadnav_onboard.config import ConfigError
from quadnav_onboard.network import DQN, NetworkConfig
from sim_harness.rl.config import TrainConfig, load_train_config
from sim_harness.rl.train import train
from sim_harness.rl.widen import can_widen, widen, widen_history

pytestmark = pytest.mark.usefixtures("one_torch_thread")

SHIPPED_SHAPE = NetworkConfig(depth_history=3, position_history=3, dueling=True)


def _inputs(cfg: NetworkConfig, n: int = 16, seed: int = 0) -> tuple[torch.Tensor, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(n, cfg.depth_history, 32, 32, generator=g),
            torch.randn(n, cfg.position_history, 3, generator=g))


def test_a_widened_network_computes_what_the_trained_one_does_whatever_the_older_inputs() -> None:
    torch.manual_seed(0)
    trained = DQN(SHIPPED_SHAPE).eval()
    wide_cfg = dataclasses.replace(SHIPPED_SHAPE, depth_history=6, position_history=5)
    wide = DQN(wide_cfg).eval()
    wide.load_state_dict(widen_history(trained, wide_cfg))
    depth, rel = _inputs(SHIPPED_SHAPE)
    with torch.no_grad():
        want = trained(depth, rel)
        for seed in (1, 2):  # two different pasts before the same last 3 frames and positions
            old_depth, old_rel = _inputs(wide_cfg, seed=seed)
            got = wide(torch.cat([old_depth[:, :3], depth], dim=1), torch.cat([old_rel[:, :2], rel], dim=1))
            torch.testing.assert_close(got, want, rtol=0, atol=1e-5)
    # the older frames start at zero weight, but they are learnable: a loss reaches them
    loss = wide(*_inputs(wide_cfg, seed=3)).square().mean()
    loss.backward()
    first = wide.depth_lane[0].weight
    assert torch.count_nonzero(first.detach()[:, :3]) == 0
    assert torch.count_nonzero(first.grad[:, :3]) > 0
    assert torch.count_nonzero(wide.pos_x[0].weight.grad[:, :2]) > 0


def test_only_longer_histories_can_be_widened() -> None:
    net = DQN(SHIPPED_SHAPE)
    assert can_widen(SHIPPED_SHAPE, SHIPPED_SHAPE)
    for other in (
        dataclasses.replace(SHIPPED_SHAPE, depth_history=2),  # shorter: a frame would be lost
        dataclasses.replace(SHIPPED_SHAPE, position_history=1),
        dataclasses.replace(SHIPPED_SHAPE, depth_history=6, dueling=False),  # another head
        dataclasses.replace(SHIPPED_SHAPE, n_actions=10),
    ):
        assert not can_widen(SHIPPED_SHAPE, other)
        with pytest.raises(ValueError, match="only longer depth and position histories"):
            widen_history(net, other)


def test_training_from_a_shorter_history_checkpoint_starts_from_its_function(tmp_path) -> None:
    torch.manual_seed(4)
    start = save_checkpoint(tmp_path / "start.pt", DQN(NetworkConfig(depth_history=1, position_history=1)))
    cfg = TrainConfig(name="wide", episodes=2, n_envs=2, max_steps=3, learning_starts=10_000,
                      depth_history=4, position_history=2, init_model=str(start),
                      out_dir=str(tmp_path / "runs"))
    result = train(cfg, progress=False)  # no update happens: the widened weights come through
    got = load_checkpoint(result.model_path)
    assert (got.network.depth_history, got.network.position_history) == (4, 2)
    want = load_checkpoint(start).model
    depth, rel = _inputs(got.network, seed=5)
    with torch.no_grad():
        torch.testing.assert_close(got.model(depth, rel), want(depth[:, -1:], rel[:, -1:]), rtol=0, atol=1e-5)
    # a checkpoint with the longer history cannot start a shorter one: refused before a run directory
    narrow = TrainConfig(name="narrow", episodes=2, n_envs=2, depth_history=1, position_history=1,
                         init_model=str(result.model_path), out_dir=str(tmp_path / "narrow_runs"))
    with pytest.raises(ConfigError, match=r"init_model.*only the histories may be longer"):
        train(narrow, progress=False)
    assert not (tmp_path / "narrow_runs").exists()


@pytest.mark.parametrize("dueling", [True, False])
def test_a_network_widened_to_wider_layers_computes_what_the_trained_one_does(dueling: bool) -> None:
    torch.manual_seed(6)
    narrow_cfg = dataclasses.replace(SHIPPED_SHAPE, dueling=dueling)
    trained = DQN(narrow_cfg).eval()
    wide_cfg = dataclasses.replace(narrow_cfg, depth_history=5, width=2)
    wide = DQN(wide_cfg).eval()
    state = widen(trained, wide_cfg, seed=3)
    wide.load_state_dict(state)
    depth, rel = _inputs(narrow_cfg)
    old_depth, _ = _inputs(wide_cfg, seed=1)
    with torch.no_grad():
        got = wide(torch.cat([old_depth[:, :2], depth], dim=1), rel)
        torch.testing.assert_close(got, trained(depth, rel), rtol=0, atol=1e-5)
    # the new units are live: their inputs carry a fresh initialisation, and a loss reaches the
    # zero weights by which the trained units read them
    trunk = wide.trunk[0].weight
    assert torch.count_nonzero(trunk.detach()[64:]) > 0
    assert torch.count_nonzero(trunk.detach()[:64, 64:128]) == 0
    wide.train()
    wide(*_inputs(wide_cfg, seed=2)).square().mean().backward()
    assert torch.count_nonzero(trunk.grad[:64, 64:128]) > 0
    assert torch.count_nonzero(wide.depth_lane[7].weight.grad[:64, 800:]) > 0
    # the same seed gives the same weights; the global generator is left where it was
    before = torch.random.get_rng_state()
    again = widen(trained, wide_cfg, seed=3)
    assert torch.equal(torch.random.get_rng_state(), before)
    assert all(torch.equal(again[k], state[k]) for k in state)
    assert not torch.equal(widen(trained, wide_cfg, seed=4)["trunk.0.weight"], state["trunk.0.weight"])


def test_only_the_paper_s_width_widens_and_never_narrows() -> None:
    wide_cfg = dataclasses.replace(SHIPPED_SHAPE, width=2)
    assert can_widen(SHIPPED_SHAPE, wide_cfg)
    assert not can_widen(wide_cfg, SHIPPED_SHAPE)
    with pytest.raises(ValueError, match="wider hidden layers"):
        widen(DQN(wide_cfg), SHIPPED_SHAPE)
    with pytest.raises(ValueError, match="only the paper's width 1 widens"):
        widen(DQN(wide_cfg), dataclasses.replace(SHIPPED_SHAPE, width=3))
    with pytest.raises(ValueError, match="only longer depth and position histories"):
        widen_history(DQN(SHIPPED_SHAPE), wide_cfg)
    for bad in (0, 5, 1.5):
        with pytest.raises(ValueError, match="network width must be an integer in 1-4"):
            NetworkConfig(width=bad)


def test_a_wider_network_s_checkpoint_names_its_width_and_the_paper_s_does_not(tmp_path) -> None:
    wide_cfg = dataclasses.replace(SHIPPED_SHAPE, width=2)
    torch.manual_seed(7)
    model = DQN(wide_cfg)
    got = load_checkpoint(save_checkpoint(tmp_path / "wide.pt", model))
    assert got.network == wide_cfg
    depth, rel = _inputs(wide_cfg)
    with torch.no_grad():
        torch.testing.assert_close(got.model(depth, rel), model.eval()(depth, rel), rtol=0, atol=0)
    # a checkpoint of the paper's width stores no width key, so builds without it read it too
    payload = torch.load(save_checkpoint(tmp_path / "paper.pt", DQN(SHIPPED_SHAPE)), weights_only=False)
    assert "width" not in payload["network"]
    # a width out of range is a bad checkpoint, named with its file
    payload["network"]["width"] = 9
    torch.save(payload, tmp_path / "bad.pt")
    with pytest.raises(CheckpointError, match=r"bad\.pt: bad 'network' section: network width"):
        load_checkpoint(tmp_path / "bad.pt")


def test_training_from_a_checkpoint_of_the_paper_s_width_with_wider_layers_starts_from_its_function(
        tmp_path) -> None:
    torch.manual_seed(8)
    start = save_checkpoint(tmp_path / "start.pt", DQN(NetworkConfig(depth_history=2, position_history=2)))
    cfg = TrainConfig(name="wider", episodes=2, n_envs=2, max_steps=3, learning_starts=10_000,
                      depth_history=2, position_history=2, network_width=2, init_model=str(start),
                      out_dir=str(tmp_path / "runs"))
    got = load_checkpoint(train(cfg, progress=False).model_path)  # no update happens
    assert got.network.width == 2
    depth, rel = _inputs(got.network, seed=9)
    with torch.no_grad():
        torch.testing.assert_close(got.model(depth, rel), load_checkpoint(start).model(depth, rel),
                                   rtol=0, atol=1e-5)
    with pytest.raises(ConfigError, match=r"recipe\.yaml.*network_width.*5"):
        load_train_config({"network_width": 5}, "recipe.yaml")
