"""What a sweep searches (sim_harness.rl.sweep_space): grids, seeds and sampled fields over
TrainConfig, checked before anything runs; no Ray needed."""

from __future__ import annotations

from pathlib import Path

import pytest

from quadnav_onboard.config import ConfigError
from sim_harness.rl.sweep_space import load_sweep_file, merge_command_line, spec_from_mapping


def _merge(**kw) -> dict:
    base = {"name": None, "sets": [], "grids": [], "samples": [], "seeds": None, "num_samples": None}
    return merge_command_line({}, **{**base, **kw})


def test_a_grid_with_seeds_gives_every_combination_once() -> None:
    spec = spec_from_mapping(
        {"grid": {"learning_rate": [1e-3, 1e-4], "double_dqn": [False, True]}, "seeds": [0, 1, 2]}, "t"
    )
    points = spec.grid_points()
    assert spec.n_trials() == len(points) == 12
    assert len({tuple(sorted(p.items())) for p in points}) == 12
    assert {p["seed"] for p in points} == {0, 1, 2}


def test_yaml_file_values_take_the_fields_types(tmp_path: Path) -> None:
    """YAML 1.1 reads 1e-3 as a string and tuples come as lists: both end as the field's type."""
    f = tmp_path / "sweep.yaml"
    f.write_text(
        "name: lr\nbase: {episodes: 50, train_worlds: [1, 4]}\n"
        "grid: {learning_rate: [1e-3, 1.0e-4]}\n"
        "sample: {batch_size: {choice: [32, 64]}, n_step: {randint: [1, 3]},\n"
        "         lr_end: {loguniform: [1e-6, 1e-5]}}\n"
        "seeds: [3]\n",
        encoding="utf-8",
    )
    spec = spec_from_mapping(load_sweep_file(f), str(f))
    assert spec.name == "lr" and spec.base == {"episodes": 50, "train_worlds": (1, 4)}
    assert spec.grid["learning_rate"] == (1e-3, 1e-4)
    assert spec.sample["n_step"].values == (1, 3) and spec.sample["lr_end"].values == (1e-6, 1e-5)
    assert spec.seeds == (3,)


def test_the_command_line_builds_the_same_spec_as_a_file() -> None:
    merged = _merge(
        name="cli",
        sets=["episodes=50", "train_worlds=1+4"],
        grids=["learning_rate=1e-3,1e-4"],
        samples=["batch_size=choice:32:64"],
        seeds=[0, 1],
    )
    spec = spec_from_mapping(merged, "command line")
    assert spec.base == {"episodes": 50, "train_worlds": (1, 4)}
    assert spec.grid == {"learning_rate": (1e-3, 1e-4)} and spec.seeds == (0, 1)
    assert spec.sample["batch_size"].kind == "choice" and spec.n_trials() == 4


@pytest.mark.parametrize(
    ("data", "words"),
    [
        ({"grid": {"learning_rat": [1e-3]}}, "unknown TrainConfig field 'learning_rat'"),
        ({"grid": {"learning_rate": [2.0]}}, "learning_rate"),
        ({"grid": {"batch_size": []}}, "non-empty list"),
        ({"base": {"out_dir": "x"}}, "set by the sweep"),
        ({"grid": {"seed": [0, 1]}}, "set by the sweep"),
        ({"base": {"n_step": 2}, "grid": {"n_step": [1, 3]}}, "given twice"),
        ({"sample": {"gamma_end": {"uniform": [0.99, 0.9]}}}, "low < high"),
        ({"sample": {"learning_rate": {"loguniform": [0, 1e-3]}}}, "low > 0"),
        ({"sample": {"learning_rate": {"normal": [0, 1]}}}, "choice, uniform, loguniform, randint"),
        ({"sample": {"batch_size": {"randint": [0, 64]}}}, "batch_size"),
        ({"seeds": [-1]}, "seed"),
        ({"num_samples": 0}, "num_samples"),
        ({"grids": {}}, "unknown keys"),
    ],
)
def test_bad_sweeps_are_refused_naming_the_key(data: dict, words: str) -> None:
    with pytest.raises(ConfigError, match=words.replace("(", r"\(").replace(")", r"\)")):
        spec_from_mapping(data, "sweep.yaml")


def test_a_spec_survives_its_json_round_trip() -> None:
    spec = spec_from_mapping(
        {
            "name": "x",
            "base": {"train_worlds": [1, 2]},
            "grid": {"dueling": [True, False]},
            "sample": {"gamma_end": {"uniform": [0.9, 0.99]}},
            "seeds": [4, 5],
            "num_samples": 2,
        },
        "t",
    )
    again = spec_from_mapping(spec.to_dict(), "sweep_spec.json")
    assert again == spec and again.n_trials() == 8


def test_the_sweep_file_in_the_training_doc_is_a_valid_sweep() -> None:
    """docs/training.md's example sweep file parses and holds the trials its comment says."""
    import re

    import yaml

    doc = (Path(__file__).resolve().parents[1] / "docs" / "training.md").read_text(encoding="utf-8")
    block = next(b for b in re.findall(r"```yaml\n(.*?)```", doc, re.S) if "lr-ddqn" in b)
    spec = spec_from_mapping(yaml.safe_load(block), "docs/training.md")
    assert spec.name == "lr-ddqn" and spec.n_trials() == 12 and spec.seeds == (0, 1, 2)


def test_paths_in_a_sweep_become_absolute_before_trials_run(tmp_path: Path, monkeypatch) -> None:
    """Ray starts a trial in a folder of its own: a relative world file must still be found."""
    from sim_harness.rl.tune_sweep import absolute_paths

    monkeypatch.chdir(tmp_path)
    grid = {"world_files": [["a.yaml"], ["b.yaml", "/abs/c.yaml"]]}
    fixed = absolute_paths(spec_from_mapping({"base": {"init_model": "m.pt"}, "grid": grid}, "t"))
    assert fixed.base["init_model"] == str(tmp_path / "m.pt")
    a, bc = fixed.grid["world_files"]
    assert a == (str(tmp_path / "a.yaml"),) and bc == (str(tmp_path / "b.yaml"), "/abs/c.yaml")
