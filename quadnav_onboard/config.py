"""Typed, frozen configuration loaded from YAML, validated once, before anything arms.

Configs are plain frozen dataclasses with a docstring per field. :func:`parse_config` validates a
mapping against one with pydantic (unknown keys, wrong types and out-of-range values are errors)
and raises :class:`ConfigError` whose message names the file, the key path and the bad value.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, TypeVar

import pydantic
import yaml

from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.reward import RewardParams

__all__ = [
    "ConfigError",
    "PlannerConfig",
    "PrimitiveConfig",
    "load_yaml",
    "load_yaml_config",
    "parse_config",
]

T = TypeVar("T")


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
        else:
            lines.append(f"{source}: key '{loc}': bad value {value!r}: {e['msg']}")
    return "\n".join(lines)


def parse_config(cls: type[T], data: Any, source: str = "<config>") -> T:
    """Validate ``data`` (a mapping, e.g. from YAML) into the frozen dataclass ``cls``."""
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
    adapter = pydantic.TypeAdapter(cls)
    try:
        return adapter.validate_python(dict(data))
    except pydantic.ValidationError as exc:
        raise ConfigError(_format_errors(source, exc)) from None


def load_yaml_config(cls: type[T], path: str | Path) -> T:
    """Load and validate a YAML file into ``cls``; errors name the file and key."""
    return parse_config(cls, load_yaml(path), source=str(path))


@dataclass(frozen=True)
class PrimitiveConfig:
    """The action set (see :mod:`quadnav_onboard.primitives`)."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    scale_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 1.0
    """Displacement (m) per axis of one primitive: 1.0 in simulation, 0.5 for real flight."""
    duration_s: Annotated[float, pydantic.Field(gt=0, le=10)] = 1.0
    """Duration (s) of one step, i.e. of one primitive."""
    directions: tuple[tuple[float, float, float], ...] = DEFAULT_DIRECTIONS
    """Unit end displacements (forward, left, up), one per action; default: the paper's 18."""

    def build(self) -> PrimitiveSet:
        return PrimitiveSet(self.directions, self.scale_m, self.duration_s)


@dataclass(frozen=True)
class PlannerConfig:
    """What training and flight must agree on: actions, preprocessing and reward."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    primitives: PrimitiveConfig = field(default_factory=PrimitiveConfig)
    """Motion primitives."""
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    """Depth-to-input conversion."""
    reward: RewardParams = field(default_factory=RewardParams)
    """The paper's reward constants."""
