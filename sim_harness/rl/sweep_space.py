"""What a sweep searches: fixed overrides, grids, sampled dimensions and seeds, over TrainConfig.

A sweep file (YAML) or the command line gives a :class:`SweepSpec`::

    name: lr-ddqn                 # experiment name (run directories: <name>__seed<k>__<time>)
    base: {episodes: 2000}        # TrainConfig overrides of every trial
    grid:                         # every combination of these
      learning_rate: [1.0e-3, 1.0e-4]
      double_dqn: [false, true]
    sample:                       # drawn afresh for each trial (num_samples per grid point)
      batch_size: {choice: [32, 64]}
      gamma_end: {uniform: [0.95, 0.995]}
      lr_end: {loguniform: [1.0e-5, 1.0e-4]}
      n_step: {randint: [1, 3]}   # inclusive
    seeds: [0, 1, 2]              # a grid dimension of its own
    num_samples: 1

Every key is a TrainConfig field and every value (a grid's, a choice's, a range's ends) is checked
as a TrainConfig would check it, before anything runs; errors name the source and the key. Pure:
:meth:`SweepSpec.param_space` is the only part that imports Ray.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import yaml

from quadnav_onboard.config import ConfigError
from sim_harness.rl.config import TrainConfig, load_train_config

__all__ = [
    "DISTRIBUTIONS",
    "Distribution",
    "SweepSpec",
    "load_sweep_file",
    "merge_command_line",
    "parse_assignment",
    "spec_from_mapping",
]

DISTRIBUTIONS = ("choice", "uniform", "loguniform", "randint")
"""How a sampled dimension is drawn: ``choice`` of a list; ``uniform``/``loguniform`` over [low,
high]; ``randint`` a whole number in [low, high] (both ends included)."""

RESERVED = frozenset({"out_dir", "seed", "name"})
"""Fields a sweep sets itself: ``out_dir`` (its folder), ``seed`` (``seeds``), ``name`` (its name)."""


@dataclasses.dataclass(frozen=True)
class Distribution:
    """One sampled dimension."""

    kind: Literal["choice", "uniform", "loguniform", "randint"]
    """One of :data:`DISTRIBUTIONS`."""
    values: tuple[Any, ...]
    """``choice``: the options; the others: ``(low, high)``."""


@dataclasses.dataclass(frozen=True)
class SweepSpec:
    """The trials of one sweep (see the module doc for the file format)."""

    name: str = "sweep"
    """Experiment name: every trial's TrainConfig ``name``."""
    base: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    """TrainConfig overrides shared by every trial."""
    grid: Mapping[str, tuple[Any, ...]] = dataclasses.field(default_factory=dict)
    """Values per field; the trials are every combination."""
    sample: Mapping[str, Distribution] = dataclasses.field(default_factory=dict)
    """Fields drawn per trial."""
    seeds: tuple[int, ...] = (0,)
    """Seeds: a grid dimension (every combination runs with each)."""
    num_samples: int = 1
    """Repeats of the grid (each with fresh draws of ``sample``)."""

    def n_trials(self) -> int:
        return math.prod(len(v) for v in self.grid.values()) * len(self.seeds) * self.num_samples

    def grid_points(self) -> list[dict[str, Any]]:
        """Every combination of the grid and the seeds (``sample`` not drawn), in order."""
        keys = [*self.grid, "seed"]
        values = [*self.grid.values(), self.seeds]
        return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*values)]

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "base": dict(self.base),
            "grid": {k: list(v) for k, v in self.grid.items()},
            "sample": {k: {d.kind: list(d.values)} for k, d in self.sample.items()},
            "seeds": list(self.seeds),
            "num_samples": self.num_samples,
        }

    def param_space(self) -> dict[str, Any]:
        """Ray Tune's ``param_space``: constants, ``grid_search`` and sampling domains by field."""
        from ray import tune

        space: dict[str, Any] = {**_jsonable(dict(self.base)), "name": self.name}
        for key, values in self.grid.items():
            space[key] = tune.grid_search(_jsonable(list(values)))
        space["seed"] = tune.grid_search(list(self.seeds))
        for key, d in self.sample.items():
            if d.kind == "choice":
                space[key] = tune.choice(_jsonable(list(d.values)))
            elif d.kind == "uniform":
                space[key] = tune.uniform(*d.values)
            elif d.kind == "loguniform":
                space[key] = tune.loguniform(*d.values)
            else:
                space[key] = tune.randint(int(d.values[0]), int(d.values[1]) + 1)
        return space


def _jsonable(value: Any) -> Any:
    """Tuples as lists (a TrainConfig's tuples travel as lists, as in config.json)."""
    if isinstance(value, tuple | list):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    return value


def _coerce(key: str, value: Any, source: str) -> Any:
    """``value`` in the type of field ``key`` where YAML read it otherwise (``1e-3`` is a string
    in YAML 1.1; ``1+2`` a tuple on the command line)."""
    hints = typing.get_type_hints(TrainConfig)  # Annotated stripped: int, float | None, tuple[int, ...]
    if key not in hints:
        raise ConfigError(f"{source}: unknown TrainConfig field {key!r}")
    tp = hints[key]
    options = [a for a in typing.get_args(tp) if a is not type(None)]
    if typing.get_origin(tp) is not tuple and len(options) == 1:  # X | None
        tp = options[0]
    try:
        if typing.get_origin(tp) is tuple:
            item = typing.get_args(tp)[0]
            if isinstance(value, str):
                value = [yaml.safe_load(v) for v in value.split("+")]
            elif not isinstance(value, list | tuple):
                value = [value]
            return tuple(item(v) for v in value)
        if tp is float and isinstance(value, str | int) and not isinstance(value, bool):
            return float(value)
        if tp is int and isinstance(value, str):
            return int(value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: key {key!r}: bad value {value!r}: {exc}") from None
    return value


def _check(base: Mapping[str, Any], key: str, value: Any, source: str) -> None:
    """Refuse a value a TrainConfig would refuse (naming the source and the key)."""
    load_train_config({**base, key: value}, source=f"{source}: {key}")


def spec_from_mapping(data: Mapping[str, Any], source: str) -> SweepSpec:
    """A checked :class:`SweepSpec` from a sweep file's mapping (see the module doc)."""
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: a sweep file is a mapping (name, base, grid, sample, seeds)")
    unknown = set(data) - {"name", "base", "grid", "sample", "seeds", "num_samples"}
    if unknown:
        raise ConfigError(f"{source}: unknown keys {sorted(unknown)}")
    name = str(data.get("name", "sweep"))
    raw_base = dict(data.get("base") or {})
    raw_grid = dict(data.get("grid") or {})
    raw_sample = dict(data.get("sample") or {})
    for section, keys in (("base", raw_base), ("grid", raw_grid), ("sample", raw_sample)):
        reserved = RESERVED & set(keys)
        if reserved:
            raise ConfigError(f"{source}: {section}: {sorted(reserved)} are set by the sweep (name, seeds)")
    for a, b in itertools.combinations((raw_base, raw_grid, raw_sample), 2):
        both = set(a) & set(b)
        if both:
            raise ConfigError(f"{source}: {sorted(both)} given twice (base, grid and sample are apart)")
    base = {k: _coerce(k, v, f"{source}: base") for k, v in raw_base.items()}
    load_train_config(base, source=f"{source}: base")
    grid: dict[str, tuple[Any, ...]] = {}
    for key, values in raw_grid.items():
        if not isinstance(values, list) or not values:
            raise ConfigError(f"{source}: grid: key {key!r}: a non-empty list of values, got {values!r}")
        grid[key] = tuple(_coerce(key, v, f"{source}: grid") for v in values)
        for v in grid[key]:
            _check(base, key, v, f"{source}: grid")
    sample = {key: _distribution(key, d, base, f"{source}: sample") for key, d in raw_sample.items()}
    seeds_raw = data.get("seeds", [0])
    seeds_list = seeds_raw if isinstance(seeds_raw, list) else [seeds_raw]
    try:
        seeds = tuple(int(s) for s in seeds_list)
    except (TypeError, ValueError):
        raise ConfigError(f"{source}: key 'seeds': bad value {seeds_raw!r}: whole numbers") from None
    if not seeds:
        raise ConfigError(f"{source}: key 'seeds': at least one seed")
    for s in seeds:
        _check(base, "seed", s, source)
    num_samples = data.get("num_samples", 1)
    if not isinstance(num_samples, int) or isinstance(num_samples, bool) or num_samples < 1:
        raise ConfigError(f"{source}: key 'num_samples': bad value {num_samples!r}: a whole number >= 1")
    return SweepSpec(name, base, grid, sample, seeds, num_samples)


def _distribution(key: str, raw: Any, base: Mapping[str, Any], source: str) -> Distribution:
    if not isinstance(raw, Mapping) or len(raw) != 1 or next(iter(raw)) not in DISTRIBUTIONS:
        raise ConfigError(
            f"{source}: key {key!r}: bad value {raw!r}: one of {{{', '.join(DISTRIBUTIONS)}: [...]}}"
        )
    kind, values = next(iter(raw.items()))
    if not isinstance(values, list) or not values:
        raise ConfigError(f"{source}: key {key!r}: {kind} takes a non-empty list, got {values!r}")
    vals = tuple(_coerce(key, v, source) for v in values)
    if kind != "choice":
        if len(vals) != 2 or not all(isinstance(v, int | float) for v in vals) or not vals[0] < vals[1]:
            raise ConfigError(
                f"{source}: key {key!r}: {kind} takes [low, high] with low < high, got {values!r}"
            )
        if kind == "loguniform" and vals[0] <= 0:
            raise ConfigError(f"{source}: key {key!r}: loguniform needs low > 0, got {values!r}")
        if kind == "randint":
            vals = (int(vals[0]), int(vals[1]))
    for v in vals:
        _check(base, key, v, source)
    return Distribution(kind, vals)


def parse_assignment(text: str, flag: str) -> tuple[str, Any]:
    """``key=value`` of the command line: the key as a field name, the value read as YAML."""
    key, sep, value = text.partition("=")
    if not sep or not key.strip():
        raise ConfigError(f"{flag} {text!r}: expected KEY=VALUE")
    return key.strip().replace("-", "_"), yaml.safe_load(value) if value.strip() else value


def load_sweep_file(path: Path) -> dict[str, Any]:
    """A sweep file's mapping (errors name the file)."""
    try:
        data = yaml.safe_load(path.read_text(encoding="utf-8"))
    except (OSError, ValueError, yaml.YAMLError) as exc:
        raise ConfigError(f"{path}: cannot read the sweep file: {exc}") from None
    return dict(data or {}) if isinstance(data, Mapping) or data is None else data


def merge_command_line(
    data: Mapping[str, Any],
    *,
    name: str | None,
    sets: Sequence[str],
    grids: Sequence[str],
    samples: Sequence[str],
    seeds: Sequence[int] | None,
    num_samples: int | None,
) -> dict[str, Any]:
    """A sweep file's mapping with the command line's ``--set``/``--grid``/``--sample`` over it.

    ``--grid KEY=V1,V2`` (tuple items joined by ``+``); ``--sample KEY=KIND:A:B...``."""
    out = {k: (dict(v) if isinstance(v, Mapping) else v) for k, v in data.items()}
    for section in ("base", "grid", "sample"):
        out.setdefault(section, {})
    if name is not None:
        out["name"] = name
    for text in sets:
        key, value = parse_assignment(text, "--set")
        out["base"][key] = value
    for text in grids:
        key, _, values = text.partition("=")
        if not values:
            raise ConfigError(f"--grid {text!r}: expected KEY=V1,V2,...")
        out["grid"][key.strip().replace("-", "_")] = [yaml.safe_load(v) for v in values.split(",")]
    for text in samples:
        key, _, rest = text.partition("=")
        kind, _, args = rest.partition(":")
        if not args:
            raise ConfigError(f"--sample {text!r}: expected KEY=KIND:A:B (KIND: {', '.join(DISTRIBUTIONS)})")
        out["sample"][key.strip().replace("-", "_")] = {kind: [yaml.safe_load(v) for v in args.split(":")]}
    if seeds:
        out["seeds"] = list(seeds)
    if num_samples is not None:
        out["num_samples"] = num_samples
    return out
