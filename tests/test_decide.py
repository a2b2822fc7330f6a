"""The split decision (quadnav_onboard.daemon.decide): prepared frames give the full decision's result."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import save_checkpoint
from quadnav_onboard.daemon.decide import Decider
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import DepthFrameError, PreprocessConfig
from quadnav_onboard.sources.base import DepthFrame


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    torch.manual_seed(4)
    cfg = NetworkConfig(depth_history=3, position_history=2, dueling=True)
    return Policy.from_path(save_checkpoint(tmp_path_factory.mktemp("m") / "m.pt", DQN(cfg)))


def _frames(n: int) -> list[DepthFrame]:
    rng = np.random.default_rng(5)
    return [DepthFrame(rng.integers(300, 9000, (240, 424), dtype=np.uint16), float(i), i) for i in range(n)]


def test_prepared_decisions_equal_full_ones_over_a_flight(policy: Policy) -> None:
    """Preparing every frame, then deciding on it, gives the same actions, Q-values and inputs as
    deciding from scratch, step after step (the history stays the same in both)."""
    prepared, full = Decider(policy, PreprocessConfig()), Decider(policy, PreprocessConfig())
    rng = np.random.default_rng(6)
    for frame in _frames(6):
        rel = rng.normal(size=3)
        prepared.prepare(frame)
        a, b = prepared.decide(frame, rel), full.decide(frame, rel)
        assert (a.path, b.path) == ("prepared", "full")
        assert a.action == b.action
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.depth_input, b.depth_input)
        np.testing.assert_array_equal(prepared.history.arrays()[0], full.history.arrays()[0])


def test_a_stale_or_other_prepared_frame_falls_back_to_the_full_decision(policy: Policy) -> None:
    """A frame prepared before the history changed, or another frame than the newest, is not used."""
    decider = Decider(policy, PreprocessConfig())
    f0, f1, f2 = _frames(3)
    decider.prepare(f1)
    assert decider.decide(f0, np.zeros(3)).path == "full"  # not the frame prepared
    assert decider.decide(f1, np.zeros(3)).path == "full"  # prepared before that push
    decider.prepare(f2)
    assert decider.decide(f2, np.zeros(3)).path == "prepared"


def test_an_unusable_frame_raises_depth_frame_error_on_both_paths(policy: Policy) -> None:
    decider = Decider(policy, PreprocessConfig())
    blank = DepthFrame(np.zeros((240, 424), np.uint16), 0.0, 1)
    with pytest.raises(DepthFrameError):
        decider.prepare(blank)
    with pytest.raises(DepthFrameError):
        decider.decide(blank, np.zeros(3))
    assert not decider.history.ready
