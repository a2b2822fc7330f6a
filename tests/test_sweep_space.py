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
