"""Observation history ordering and the greedy policy over a real checkpoint."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import CheckpointError, save_checkpoint
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.observation import ObservationHistory
from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy


def _frame(v: float) -> np.ndarray:
    return np.full((32, 32), v, dtype=np.float32)


def test_history_reset_fills_every_slot_with_the_first_observation() -> None:
    h = ObservationHistory(depth_history=3, position_history=2)
    h.reset(_frame(0.5), [1.0, 2.0, 3.0])
    depth, rel = h.arrays()
    assert depth.shape == (3, 32, 32) and depth.dtype == np.float32
    assert rel.shape == (2, 3) and rel.dtype == np.float32
    assert np.all(depth == 0.5)
    assert np.all(rel == np.array([1.0, 2.0, 3.0], dtype=np.float32))


def test_history_push_keeps_the_newest_last_and_drops_the_oldest() -> None:
    h = ObservationHistory(depth_history=3, position_history=2)
    h.reset(_frame(0.1), [0.0, 0.0, 0.0])
    for i in range(1, 5):
        h.push(_frame(0.1 * (i + 1)), [float(i), 0.0, 0.0])
    depth, rel = h.arrays()
    np.testing.assert_allclose(depth[:, 0, 0], [0.3, 0.4, 0.5], rtol=1e-6)
    np.testing.assert_allclose(rel[:, 0], [3.0, 4.0])


def test_history_arrays_are_copies() -> None:
    h = ObservationHistory()
    h.reset(_frame(0.2), [1.0, 0.0, 0.0])
    depth, _ = h.arrays()
    depth[:] = 0.0
    assert np.all(h.arrays()[0] == np.float32(0.2))


def test_history_rejects_bad_shapes_and_nan() -> None:
    h = ObservationHistory()
    with pytest.raises(ValueError, match="shape"):
        h.reset(np.zeros((16, 16)), [0, 0, 0])
    with pytest.raises(ValueError, match="shape"):
        h.reset(_frame(0.1), [0, 0])
    with pytest.raises(ValueError, match="NaN"):
        h.reset(_frame(np.nan), [0, 0, 0])
    with pytest.raises(RuntimeError):
        h.arrays()
    with pytest.raises(ValueError):
        ObservationHistory(depth_history=0)


def test_policy_picks_the_argmax_of_the_network(tmp_path) -> None:
    torch.manual_seed(0)
    cfg = NetworkConfig(depth_history=2, position_history=3)
    model = DQN(cfg)
    path = save_checkpoint(tmp_path / "m.pt", model, primitives={"scale_m": 0.5}, preprocess={})
    policy = Policy.from_path(path)
    rng = np.random.default_rng(0)
    depth = rng.random((2, 32, 32), dtype=np.float32)
    rel = rng.normal(size=(3, 3)).astype(np.float32)
    action, q = policy.act(depth, rel)
    with torch.no_grad():
        expect = model(torch.as_tensor(depth[None]), torch.as_tensor(rel[None]))[0].numpy()
    np.testing.assert_allclose(q, expect, rtol=1e-5, atol=1e-6)
    assert q.shape == (18,)
    assert action == int(np.argmax(expect))
    assert policy.primitive_set().scale_m == 0.5
    assert policy.preprocess_config().max_range_m == 10.0


def test_history_depth_with_is_the_stack_a_push_would_make_without_pushing() -> None:
    """depth_with(d) equals the depth stack after push(d, ·), and leaves the history and its version alone."""
    h = ObservationHistory(depth_history=3, position_history=2)
    np.testing.assert_array_equal(h.depth_with(_frame(0.7)), np.full((3, 32, 32), 0.7, np.float32))
    h.reset(_frame(0.1), [0.0, 0.0, 0.0])
    h.push(_frame(0.2), [1.0, 0.0, 0.0])
    before, version = h.arrays(), h.version
    candidate = h.depth_with(_frame(0.3))
    np.testing.assert_array_equal(h.arrays()[0], before[0])
    assert h.version == version
    h.push(_frame(0.3), [2.0, 0.0, 0.0])
    np.testing.assert_array_equal(candidate, h.arrays()[0])
    np.testing.assert_array_equal(h.rel_array(), h.arrays()[1])
    assert h.version == version + 1
    twin = h.copy()
    np.testing.assert_array_equal(twin.arrays()[0], h.arrays()[0])
    assert twin.version == h.version
    twin.push(_frame(0.9), [0.0, 0.0, 0.0])
    assert h.version == version + 1 and h.arrays()[0][-1, 0, 0] == np.float32(0.3)  # independent


def _policy(tmp_path, cfg: NetworkConfig) -> Policy:
    torch.manual_seed(3)
    return Policy.from_path(save_checkpoint(tmp_path / "m.pt", DQN(cfg)))


@pytest.mark.parametrize(
    "cfg", [NetworkConfig(), NetworkConfig(depth_history=3, position_history=2, dueling=True)]
)
def test_act_from_features_of_depth_features_is_act(tmp_path, cfg: NetworkConfig) -> None:
    """The two halves the daemon runs at different times give act's action and Q-values exactly."""
    policy = _policy(tmp_path, cfg)
    rng = np.random.default_rng(1)
    for _ in range(5):
        depth = rng.random((cfg.depth_history, 32, 32), dtype=np.float32)
        rel = rng.normal(size=(cfg.position_history, 3)).astype(np.float32)
        features = policy.depth_features(depth)
        assert features.shape == (64,) and features.dtype == np.float32
        a1, q1 = policy.act(depth, rel)
        a2, q2 = policy.act_from_features(features, rel)
        assert a1 == a2
        np.testing.assert_array_equal(q1, q2)


def test_allowed_restricts_the_argmax_and_none_allowed_means_all(tmp_path) -> None:
    """The arg-max is over the allowed actions; with none allowed it is over all; Q-values stay unmasked."""
    policy = _policy(tmp_path, NetworkConfig())
    rng = np.random.default_rng(2)
    depth, rel = rng.random((1, 32, 32), dtype=np.float32), rng.normal(size=(1, 3)).astype(np.float32)
    best, q = policy.act(depth, rel)
    allowed = np.ones(18, bool)
    allowed[best] = False
    action, q_masked = policy.act(depth, rel, allowed)
    assert action != best and action == int(np.argmax(np.where(allowed, q, -np.inf)))
    np.testing.assert_array_equal(q_masked, q)
    only = np.zeros(18, bool)
    only[3] = True
    assert policy.act(depth, rel, only)[0] == 3
    assert policy.act(depth, rel, np.zeros(18, bool))[0] == best
    assert policy.act(depth, rel, np.ones(18, bool))[0] == best
    with pytest.raises(ValueError, match="allowed must have shape"):
        policy.act(depth, rel, np.ones(5, bool))


def test_policy_rejects_observations_of_the_wrong_history_length(tmp_path) -> None:
    path = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig()))
    policy = Policy.from_path(path)
    with pytest.raises(ValueError, match="depth must have shape"):
        policy.act(np.zeros((2, 32, 32), np.float32), np.zeros((1, 3), np.float32))


def test_policy_from_missing_path_is_a_checkpoint_error(tmp_path) -> None:
    with pytest.raises(CheckpointError, match="not found"):
        Policy.from_path(tmp_path / "nope.pt")


def test_default_model_path_points_into_the_package() -> None:
    assert DEFAULT_MODEL_PATH.name == "default.pt"
    assert DEFAULT_MODEL_PATH.parent.name == "models"


def test_masked_argmax_keeps_to_allowed_actions_row_by_row_and_falls_back_to_all() -> None:
    """The one masking rule the daemon, eval and training share."""
    from quadnav_onboard.policy import masked_argmax

    q = np.array([[3.0, 1.0, 2.0], [3.0, 1.0, 2.0], [3.0, 1.0, 2.0]])
    allowed = np.array([[False, True, True], [False, True, False], [False, False, False]])
    assert masked_argmax(q, allowed).tolist() == [2, 1, 0]
    assert masked_argmax(q, None).tolist() == [0, 0, 0]
