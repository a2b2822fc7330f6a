"""Typed, frozen configuration loaded from YAML, validated once, before anything arms.

Configs are plain frozen dataclasses with a docstring per field. :func:`parse_config` validates a
mapping against one with pydantic (unknown keys, wrong types and out-of-range values are errors)
and raises :class:`ConfigError` whose message names the file, the key path and the bad value.

Every numeric field is finite (``allow_inf_nan: False`` in each class's pydantic config, so NaN
and infinity are refused as "should be a finite number") and bounded on both sides by a stated
physical range, given in its docstring: an infinite or absurd limit would switch its check off.
A boolean is not a number (YAML reads yes/no/on/off as booleans). A file that is empty, not UTF-8
text or not a mapping is refused too (:func:`load_yaml_config`); ``{}`` asks for the defaults.
tests/test_config_fuzz.py tries NaN, ±inf, 0, -1, ±1e12 and booleans in every numeric field it
finds by walking these dataclasses; the 0 and negative values a field means something by (world
coordinates, "land at once", "no shadow points", ...) are listed there, each with its meaning.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Annotated, Any, TypeVar

import pydantic
import yaml

from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.reward import RewardParams

__all__ = [
    "CONFIG_DICT",
    "ConfigError",
    "PlannerConfig",
    "PrimitiveConfig",
    "load_yaml",
    "load_yaml_config",
    "load_yaml_mapping",
    "parse_config",
]

T = TypeVar("T")

CONFIG_DICT: pydantic.ConfigDict = {"extra": "forbid", "allow_inf_nan": False}
"""The pydantic config of every config dataclass: unknown keys are errors, and so are NaN and ±inf."""


class ConfigError(ValueError):
    """Invalid configuration; the message says where (file, key path) and what (value, reason)."""


class _UniqueKeyLoader(yaml.SafeLoader):
    """A safe YAML loader that refuses duplicate keys instead of silently keeping the last."""


def _construct_mapping(
    loader: _UniqueKeyLoader, node: yaml.MappingNode, deep: bool = False
) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=deep)
        if key in seen:
            raise yaml.constructor.ConstructorError(None, None, f"duplicate key {key!r}", key_node.start_mark)
        seen.add(key)
    return loader.construct_mapping(node, deep=deep)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def load_yaml(path: str | Path) -> Any:
    """Read a YAML file safely; a missing file or a syntax error raises :class:`ConfigError`."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc.strerror or exc}") from exc
    except UnicodeDecodeError as exc:
        raise ConfigError(
            f"{path}: not a UTF-8 text file (byte 0x{exc.object[exc.start]:02x} at offset {exc.start})"
        ) from None
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: malformed YAML: {exc}") from exc


def _format_errors(source: str, err: pydantic.ValidationError) -> str:
    lines = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<root>"
        value = e.get("input")
        if e["type"] == "missing":
            lines.append(f"{source}: key '{loc}': required but missing")
        elif e["type"] in ("unexpected_keyword_argument", "extra_forbidden"):
            lines.append(f"{source}: key '{loc}': unknown key (value {value!r})")
        elif e["type"] == "value_error" and isinstance(value, Mapping):  # a check across keys
            reason = str(e["msg"]).removeprefix("Value error, ")
            lines.append(f"{source}: key '{loc}': {reason}")
        else:
            lines.append(f"{source}: key '{loc}': bad value {value!r}: {e['msg']}")
    return "\n".join(lines)


@cache
def _adapter(cls: type[T]) -> pydantic.TypeAdapter[T]:
    return pydantic.TypeAdapter(cls)


@cache
def _field_types(cls: type) -> dict[str, Any]:
    return typing.get_type_hints(cls, include_extras=True)


def _unwrap(tp: Any) -> Any:
    """The type under ``Annotated[...]`` and ``X | None``."""
    while True:
        origin = typing.get_origin(tp)
        if origin is Annotated:
            tp = typing.get_args(tp)[0]
        elif origin in (typing.Union, types.UnionType):
            args = [a for a in typing.get_args(tp) if a is not type(None)]
            if len(args) != 1:
                return tp
            tp = args[0]
        else:
            return tp


def _booleans_for_numbers(tp: Any, value: Any, loc: str) -> Iterator[tuple[str, bool]]:
    """(key path, value) of each boolean given for a numeric field under ``tp``: pydantic would
    read ``true`` as 1 (YAML also reads yes/no/on/off as booleans): ``speed_m_s: on`` is not 1 m/s."""
    tp = _unwrap(tp)
    if isinstance(value, bool):
        if tp in (int, float):
            yield loc, value
    elif dataclasses.is_dataclass(tp) and isinstance(value, Mapping):
        hints = _field_types(tp)  # type: ignore[arg-type]
        for key, item in value.items():
            if key in hints:
                yield from _booleans_for_numbers(hints[key], item, f"{loc}.{key}" if loc else str(key))
    elif typing.get_origin(tp) is tuple and isinstance(value, (list, tuple)):
        args = typing.get_args(tp)
        variadic = len(args) == 2 and args[1] is Ellipsis
        for i, item in enumerate(value):
            if variadic or i < len(args):
                yield from _booleans_for_numbers(args[0] if variadic else args[i], item, f"{loc}.{i}")


def parse_config(cls: type[T], data: Any, source: str = "<config>") -> T:
    """Validate ``data`` (a mapping, e.g. from YAML; None = no keys) into the frozen dataclass ``cls``."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    booleans = list(_booleans_for_numbers(cls, data, ""))
    if booleans:
        why = "a number is needed, not a boolean"
        raise ConfigError("\n".join(f"{source}: key '{loc}': bad value {v!r}: {why}" for loc, v in booleans))
    try:
        return _adapter(cls).validate_python(dict(data))
    except pydantic.ValidationError as exc:
        raise ConfigError(_format_errors(source, exc)) from None


def load_yaml_mapping(path: str | Path) -> Any:
    """A config file's YAML, refusing a file with no document (empty, or comments only): it would
    otherwise stand for every default without a word. ``{}`` asks for the defaults."""
    data = load_yaml(path)
    if data is None:
        raise ConfigError(f"{path}: the file is empty (no keys); write '{{}}' to take every default")
    return data


def load_yaml_config(cls: type[T], path: str | Path) -> T:
    """Load and validate a YAML file into ``cls``; errors name the file and key."""
    return parse_config(cls, load_yaml_mapping(path), source=str(path))


_UnitComponent = Annotated[float, pydantic.Field(ge=-1, le=1)]
_Direction = tuple[_UnitComponent, _UnitComponent, _UnitComponent]
_Directions = Annotated[tuple[_Direction, ...], pydantic.Field(min_length=1, max_length=64)]


@dataclass(frozen=True)
class PrimitiveConfig:
    """The action set (see :mod:`quadnav_onboard.primitives`)."""

    __pydantic_config__ = CONFIG_DICT

    scale_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 1.0
    """Displacement (m) per axis of one primitive, in (0, 5]: 1.0 in simulation, 0.5 for real flight."""
    duration_s: Annotated[float, pydantic.Field(gt=0, le=10)] = 1.0
    """Duration (s) of one step, i.e. of one primitive, in (0, 10]."""
    directions: _Directions = DEFAULT_DIRECTIONS
    """Unit end displacements (forward, left, up), each component in [-1, 1], one per action
    (1 to 64 actions); default: the paper's 18."""

    def build(self) -> PrimitiveSet:
        return PrimitiveSet(self.directions, self.scale_m, self.duration_s)


@dataclass(frozen=True)
class PlannerConfig:
    """What training and flight must agree on: actions, preprocessing and reward."""

    __pydantic_config__ = CONFIG_DICT

    primitives: PrimitiveConfig = field(default_factory=PrimitiveConfig)
    """Motion primitives."""
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    """Depth-to-input conversion."""
    reward: RewardParams = field(default_factory=RewardParams)
    """The paper's reward constants."""
