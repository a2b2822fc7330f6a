"""``quadnav-sim soup``: the mean of runs' weights, only for runs fine-tuned from the same start."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
from quadnav_onboard.network import DQN, NetworkConfig
from sim_harness.cli import main
from sim_harness.rl.config import TrainConfig
from sim_harness.rl.train import train

pytestmark = pytest.mark.usefixtures("one_torch_thread")

START = {"init_model": "start.pt", "init_model_sha256": ""}


def _ckpt(path: Path, seed: int, *, net: NetworkConfig | None = None, **meta: object) -> str:
    torch.manual_seed(seed)
    meta = {"train_config": {**START, "name": "r", "seed": seed}, "seed": seed, **meta}
    return str(save_checkpoint(path, DQN(net or NetworkConfig()), meta=meta))


def test_two_runs_from_one_start_average_to_their_mean_and_the_soup_flies(tmp_path: Path) -> None:
    """Two real fine-tuning runs (seeds 0 and 1) from one pinned start: the soup's weights are the
    mean of theirs, its meta names both ingredients and their filter, the same command gives the
    same weights again, and `quadnav-sim eval` flies it with that filter."""
    torch.manual_seed(7)
    start = save_checkpoint(tmp_path / "start.pt", DQN(NetworkConfig()))
    runs = []
    for seed in (0, 1):
        cfg = TrainConfig(
            name="ft", seed=seed, episodes=4, n_envs=2, max_steps=6, learning_starts=8, batch_size=8,
            shield=True, init_model=str(start), init_model_sha256=load_checkpoint(start).sha256,
            out_dir=str(tmp_path / "runs"),
        )
        runs.append(str(train(cfg, progress=False).model_path))
    a, b = (load_checkpoint(p) for p in runs)
    sa, sb = a.model.state_dict(), b.model.state_dict()
    assert any(not torch.equal(sa[k], sb[k]) for k in sa), "the two seeds must have trained apart"

    out = tmp_path / "soup.pt"
    assert main(["soup", *runs, "--out", str(out)]) == 0
    soup = load_checkpoint(out)
    for key, value in soup.model.state_dict().items():
        want = ((sa[key].double() + sb[key].double()) / 2).float()
        assert torch.equal(value, want), key
    assert [i["sha256"] for i in soup.meta["soup_of"]] == [a.sha256, b.sha256]
    assert [i["seed"] for i in soup.meta["soup_of"]] == [0, 1]
    assert soup.meta["shield"] == a.meta["shield"] and soup.meta["shield"]["enabled"] is True
    assert soup.meta["init_model_sha256"] == load_checkpoint(start).sha256

    again = tmp_path / "again.pt"
    assert main(["soup", *runs, "--out", str(again)]) == 0
    redo = load_checkpoint(again)
    assert redo.meta == soup.meta
    assert all(torch.equal(v, soup.model.state_dict()[k]) for k, v in redo.model.state_dict().items())

    flown = tmp_path / "eval.json"
    args = ["eval", "--model", str(out), "--procedural", "1", "--trials", "1", "--max-steps", "3",
            "--no-progress", "--json", str(flown)]
    assert main(args) == 0
    data = json.loads(flown.read_text())
    assert len(data["rows"]) == 1 and data["shield"]["enabled"] is True


def _refused(capsys: pytest.CaptureFixture[str], tmp_path: Path, paths: list[str]) -> str:
    out = tmp_path / "soup.pt"
    assert main(["soup", *paths, "--out", str(out)]) == 2
    assert not out.exists()
    return capsys.readouterr().err


def test_one_checkpoint_the_same_file_twice_or_an_ingredient_as_out_is_refused(tmp_path, capsys) -> None:
    a = _ckpt(tmp_path / "a.pt", 0)
    assert "two or more checkpoints, got 1" in _refused(capsys, tmp_path, [a])
    err = _refused(capsys, tmp_path, [a, a])
    assert f"{a}: the same file as {a}" in err
    b = _ckpt(tmp_path / "b.pt", 1)
    before = Path(b).read_bytes()
    assert main(["soup", a, b, "--out", b]) == 2
    assert "is one of the checkpoints to average" in capsys.readouterr().err
    assert Path(b).read_bytes() == before


@pytest.mark.parametrize(
    ("other", "why"),
    [
        ({"net": NetworkConfig(depth_history=3)}, "its network differs"),
        ({"shield": {"enabled": True}}, "its meta.shield differs"),
    ],
)
def test_checkpoints_that_differ_in_network_or_filter_are_refused_naming_the_file(
    tmp_path, capsys, other: dict, why: str
) -> None:
    a = _ckpt(tmp_path / "a.pt", 0)
    b = _ckpt(tmp_path / "b.pt", 1, **other)
    err = _refused(capsys, tmp_path, [a, b])
    assert f"{b}: {why} from {a}'s" in err


def test_runs_from_another_start_or_none_named_are_refused(tmp_path, capsys) -> None:
    a = _ckpt(tmp_path / "a.pt", 0)
    b = _ckpt(tmp_path / "b.pt", 1)
    moved = {"train_config": {"init_model": "other.pt", "init_model_sha256": "", "seed": 2}}
    c = _ckpt(tmp_path / "c.pt", 2, **moved)
    err = _refused(capsys, tmp_path, [a, b, c])
    assert f"{c}: started from init_model 'other.pt'" in err and "'start.pt'" in err
    torch.manual_seed(3)
    scratch = str(save_checkpoint(tmp_path / "scratch.pt", DQN(NetworkConfig()), meta={"seed": 3}))
    err = _refused(capsys, tmp_path, [scratch, a])
    assert f"{scratch}: its meta names no train_config.init_model" in err


def test_a_soup_of_three_is_the_mean_of_three(tmp_path) -> None:
    from sim_harness.cmd_soup import soup

    paths = [_ckpt(tmp_path / f"{i}.pt", i) for i in range(3)]
    model, meta, _ = soup(paths)
    states = [load_checkpoint(p).model.state_dict() for p in paths]
    for key, value in model.state_dict().items():
        want = (sum(s[key].double() for s in states) / 3).float()
        assert torch.equal(value, want), key
    assert len(meta["soup_of"]) == 3
    assert "shield" not in meta
