"""The paper's DQN and its checkpoints."""

import pytest
import torch

from quadnav_onboard.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from quadnav_onboard.network import DQN, NetworkConfig, count_parameters


def test_parameter_count_is_the_papers():
    """Our reading of the paper's figure has exactly 73,946 parameters ("around 75,000")."""
    assert count_parameters(DQN()) == 73_946


def test_layer_shapes_follow_the_paper():
    """Conv lane flattens to 800; the fused vector is 64 + 16 = 80; 18 outputs."""
    net = DQN()
    x = torch.zeros(1, 1, 32, 32)
    assert net.depth_lane[:7](x).shape == (1, 800)
    assert net.trunk[0].in_features == 80
    assert net(x, torch.zeros(1, 1, 3)).shape == (1, 18)


def test_last_layer_has_no_activation():
    """Q-values can be negative: the output layer is linear."""
    torch.manual_seed(0)
    q = DQN()(torch.rand(64, 1, 32, 32), torch.randn(64, 1, 3) * 5)
    assert (q < 0).any()


def test_options_change_the_input_shape():
    cfg = NetworkConfig(depth_history=3, position_history=2, dueling=True)
    q = DQN(cfg)(torch.zeros(2, 3, 32, 32), torch.zeros(2, 2, 3))
    assert q.shape == (2, 18)


@pytest.mark.parametrize(
    "cfg",
    [
        NetworkConfig(),
        NetworkConfig(dueling=True),
        NetworkConfig(depth_history=3, position_history=2, dueling=True),
    ],
    ids=["paper", "dueling", "history+dueling"],
)
def test_the_two_halves_compose_to_forward_exactly(cfg):
    """q_from_features(depth_features(d), r) is forward(d, r), bit for bit, and the features are (B, 64)."""
    torch.manual_seed(2)
    net = DQN(cfg).eval()
    d = torch.rand(5, cfg.depth_history, 32, 32)
    r = torch.randn(5, cfg.position_history, 3) * 3
    with torch.inference_mode():
        features = net.depth_features(d)
        assert features.shape == (5, 64)
        assert torch.equal(net.q_from_features(features, r), net(d, r))


def test_the_split_keeps_the_checkpoint_layout():
    """Same parameters under the same state_dict keys as before the split: old checkpoints load."""
    lanes = [f"depth_lane.{i}" for i in (0, 2, 4, 7, 9)] + ["pos_x.0", "pos_y.0", "pos_z.0", "pos_merge.0"]
    body = [*lanes, "trunk.0", "trunk.2"]
    keys = [f"{m}.{p}" for m in body for p in ("weight", "bias")]
    assert list(DQN().state_dict()) == [*keys, "out.weight", "out.bias"]
    dueling = [*keys, "value.weight", "value.bias", "advantage.weight", "advantage.bias"]
    assert list(DQN(NetworkConfig(dueling=True)).state_dict()) == dueling


def test_checkpoint_round_trip(tmp_path):
    """Saved weights and settings load back identical, in eval mode."""
    torch.manual_seed(1)
    net = DQN()
    path = save_checkpoint(tmp_path / "m.pt", net, primitives={"scale_m": 1.0}, meta={"seed": 3})
    ck = load_checkpoint(path, expect=NetworkConfig())
    x, p = torch.rand(4, 1, 32, 32), torch.randn(4, 1, 3)
    torch.testing.assert_close(ck.model(x, p), net(x, p))
    assert ck.primitives == {"scale_m": 1.0} and ck.meta == {"seed": 3}
    assert not ck.model.training and len(ck.sha256) == 64


def test_missing_file(tmp_path):
    with pytest.raises(CheckpointError, match="not found"):
        load_checkpoint(tmp_path / "nope.pt")


def test_truncated_file(tmp_path):
    path = save_checkpoint(tmp_path / "m.pt", DQN())
    path.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(CheckpointError, match="corrupt or truncated"):
        load_checkpoint(path)


def test_garbage_file(tmp_path):
    path = tmp_path / "g.pt"
    path.write_bytes(b"\x00garbage" * 100)
    with pytest.raises(CheckpointError, match=str(path.name)):
        load_checkpoint(path)


def test_foreign_torch_file(tmp_path):
    """A valid torch file that is not ours (e.g. a bare state_dict) is refused."""
    path = tmp_path / "sd.pt"
    torch.save(DQN().state_dict(), path)
    with pytest.raises(CheckpointError, match="not a quadnav"):
        load_checkpoint(path)


def test_shape_mismatch(tmp_path):
    """A checkpoint of another shape is refused when a shape is expected."""
    path = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig(depth_history=2)))
    with pytest.raises(CheckpointError, match="does not match"):
        load_checkpoint(path, expect=NetworkConfig())


def test_tampered_weights(tmp_path):
    """Weights that do not fit the declared network, or are NaN, are refused."""
    payload = {
        "format": "quadnav-dqn",
        "format_version": 1,
        "network": NetworkConfig().to_dict(),
        "state_dict": DQN(NetworkConfig(n_actions=5)).state_dict(),
    }
    torch.save(payload, tmp_path / "a.pt")
    with pytest.raises(CheckpointError, match="do not fit"):
        load_checkpoint(tmp_path / "a.pt")
    net = DQN()
    with torch.no_grad():
        net.out.weight[0, 0] = float("nan")
    save_checkpoint(tmp_path / "b.pt", net)
    with pytest.raises(CheckpointError, match="NaN"):
        load_checkpoint(tmp_path / "b.pt")


def test_future_format_version(tmp_path):
    torch.save({"format": "quadnav-dqn", "format_version": 99}, tmp_path / "v.pt")
    with pytest.raises(CheckpointError, match="format_version 99"):
        load_checkpoint(tmp_path / "v.pt")
