"""A trained network widened to a longer input history computes what it did, and can learn more."""

from __future__ import annotations

import dataclasses

import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
from quadnav_onboard.config import ConfigError
from quadnav_onboard.network import DQN, NetworkConfig
from sim_harness.rl.config import TrainConfig
from sim_harness.rl.train import train
from sim_harness.rl.widen import can_widen, widen_history

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
