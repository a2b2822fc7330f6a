"""Every numeric config field, generated from the dataclasses: NaN, ±inf, 0, -1, ±1e12 and booleans
are each refused naming the file, the key and the value, or listed in ``MEANINGFUL`` with what they
mean.

The fields are found by walking the config dataclasses (nested sections, optional sections,
fixed and variable tuples) rather than listed by hand, so a field added later is checked too.
The flight config starts from config/flight.yaml with every section spelled out; one key is
replaced at a time and the file loaded as the daemon loads it (flight config, then trigger).
"""

from __future__ import annotations

import copy
import dataclasses
import fnmatch
import json
import math
import typing
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import yaml

from quadnav_onboard.config import ConfigError, PlannerConfig, parse_config
from quadnav_onboard.config import _unwrap as unwrap_annotation
from quadnav_onboard.daemon.config import FlightConfig, load_flight_config
from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.shield import ShieldConfig
from quadnav_onboard.trigger import MissionTriggerConfig, trigger_config_from_mapping
from sim_harness.rl.config import TrainConfig, load_train_config

REPO = Path(__file__).resolve().parents[1]

VALUES: dict[str, float | bool] = {
    "nan": math.nan,
    "inf": math.inf,
    "-inf": -math.inf,
    "zero": 0,
    "negative": -1,
    "huge": 1e12,
    "-huge": -1e12,
    "true": True,
    "false": False,
}
"""The values tried in every numeric field (YAML reads yes/no/on/off as booleans, which pydantic
would otherwise take for 1 and 0)."""

MEANINGFUL: dict[tuple[str, str], str] = {
    # world positions: the origin and the negative half-axes are places like any other
    ("mission.waypoints_m.*", "zero"): "a world coordinate (m)",
    ("mission.waypoints_m.*", "negative"): "a world coordinate (m)",
    ("safety.geofence_min_m.*", "zero"): "a world coordinate (m)",
    ("safety.geofence_min_m.*", "negative"): "a world coordinate (m)",
    ("safety.geofence_max_m.*", "zero"): "a world coordinate (m)",
    ("safety.geofence_max_m.*", "negative"): "a world coordinate (m)",
    ("safety.altitude_floor_m", "zero"): "a world height (m): the floor at the origin",
    ("safety.altitude_floor_m", "negative"): "a world height (m): the origin above the floor",
    ("safety.altitude_ceiling_m", "zero"): "a world height (m)",
    ("safety.altitude_ceiling_m", "negative"): "a world height (m)",
    ("safety.ground_z_m", "zero"): "the ground at the odometry frame's origin",
    ("safety.ground_z_m", "negative"): "the ground below the odometry frame's origin",
    ("odometry.translation_world_m.*", "zero"): "the mocap origin (world, m)",
    ("odometry.translation_world_m.*", "negative"): "the mocap origin (world, m)",
    ("odometry.rotation_world_from_mocap.*", "zero"): "a rotation matrix entry",
    ("odometry.rotation_world_from_mocap.*", "negative"): "a rotation matrix entry",
    ("primitives.directions.*", "zero"): "no displacement on that axis",
    ("primitives.directions.*", "negative"): "backward, right or down",
    ("shield.camera_offset_m.*", "zero"): "the camera at the body origin on that axis",
    ("shield.camera_offset_m.*", "negative"): "the camera behind, right of or below the origin",
    # zero switches something off or means "at once"
    ("safety.hold_before_land_s", "zero"): "land without holding first",
    ("shield.lookahead_s", "zero"): "no overshoot check past the primitive's end",
    ("shield.min_travel_m", "zero"): "every decision pushes the oldest view out",
    ("shield.seen_level_tol_m", "zero"): "every sample off the vehicle's level must lie in seen space",
    ("shield.seen_margin_m", "zero"): "seen free up to the measured depth itself",
    ("shield.near_m", "zero"): "no free zone around the vehicle",
    ("shield.shadow_m", "zero"): "the seen surfaces only, no shadow points",
    ("shield.fence_min_m.*", "zero"): "a world coordinate (m)",
    ("shield.fence_min_m.*", "negative"): "a world coordinate (m)",
    ("shield.fence_max_m.*", "zero"): "a world coordinate (m)",
    ("shield.fence_max_m.*", "negative"): "a world coordinate (m)",
    ("shield.fence_margin_m", "zero"): "the predicted path may reach the geofence's faces",
    ("shield.band_waypoints_m.*", "zero"): "a world coordinate (m)",
    ("shield.band_waypoints_m.*", "negative"): "a world coordinate (m)",
    ("shield.band_margin_m", "zero"): "the predicted path may reach the deviation band's edge",
    # reward constants: the paper's own include 0 and negative values
    ("reward.r_lower", "zero"): "the paper's R_l",
    ("reward.r_lower", "negative"): "a shaping penalty",
    ("reward.r_upper", "zero"): "no shaping reward",
    ("reward.r_upper", "negative"): "a shaping penalty",
    ("reward.dd_lower_m", "zero"): "a saturation bound of the distance change",
    ("reward.dd_lower_m", "negative"): "the paper's Δd_l (-1 m)",
    ("reward.dd_upper_m", "zero"): "a saturation bound of the distance change",
    ("reward.dd_upper_m", "negative"): "a saturation bound of the distance change",
    ("reward.deviation_penalty", "zero"): "no deviation penalty",
    ("reward.deviation_penalty", "negative"): "the paper's R_dp (-0.5)",
    ("reward.collision_penalty", "zero"): "no collision penalty",
    ("reward.collision_penalty", "negative"): "the paper's R_cp (-1)",
    # training: zero seeds, counts and switches
    ("train.seed", "zero"): "a seed",
    ("train.procedural_seed", "zero"): "a seed",
    ("train.procedural_worlds", "zero"): "no generated worlds (the paper)",
    ("train.start_jitter_m", "zero"): "every episode starts on the path's start",
    ("train.random_start_prob", "zero"): "no random starts (the paper)",
    ("train.eps_start", "zero"): "greedy from the start",
    ("train.eps_end", "zero"): "greedy at the end",
    ("train.gamma_start", "zero"): "a myopic start of the γ ramp",
    ("train.gamma_end", "zero"): "a myopic end of the γ ramp",
    ("train.max_grad_norm", "zero"): "no gradient clipping",
    ("train.teacher_release_m", "zero"): "never: the teacher keeps to the filter's verdicts in every state",
    ("train.per_alpha", "zero"): "uniform replay",
    ("train.per_beta_start", "zero"): "no importance-sampling correction at first",
    ("train.keep_every", "zero"): "no kept snapshots",
    ("train.sim_threads", "zero"): "numba's default thread count",
    ("train.dagger_iterations", "zero"): "no imitation (the paper)",
    ("train.dagger_beta", "zero"): "the network flies every step after iteration 0",
    ("train.dagger_filtered_share", "zero"): "the network flies alone in every DAgger env",
    ("train.dagger_noise", "zero"): "no random steps in DAgger's flights",
    ("train.imitation_updates", "zero"): "the fit runs imitation_epochs passes instead",
    ("train.imitation_margin_weight", "zero"): "the fit has no large-margin term",
    ("train.imitation_margin_min_gap_m", "zero"): "the large-margin loss in every state",
    ("train.imitation_veto_weight", "zero"): "the fit has no hinge on the filter's verdicts",
    ("train.lab_layouts", "zero"): "no lab layouts (DAgger flies imitation_scales only)",
    ("train.lab_layout_seed", "zero"): "a seed",
}
"""Values (key pattern, value kind) a numeric field means something by: each is accepted by the
field's own range; a check across fields (a geofence corner above its opposite, a ceiling below
the floor, a path leaving the geofence) may still refuse it, naming the keys involved."""


_unwrap = unwrap_annotation  # the type under ``Annotated[...]`` and ``X | None``


def numeric_leaves(tp: Any, key: tuple[str | int, ...] = ()) -> Iterator[tuple[tuple[str | int, ...], type]]:
    """(key path, int or float) of every numeric field under the dataclass ``tp``, walking nested
    and optional sections and tuples (a variable tuple by its first element)."""
    tp = _unwrap(tp)
    if dataclasses.is_dataclass(tp):
        hints = typing.get_type_hints(tp, include_extras=True)
        for f in dataclasses.fields(tp):
            yield from numeric_leaves(hints[f.name], (*key, f.name))
    elif tp in (int, float):
        yield key, tp
    elif typing.get_origin(tp) is tuple:
        args = typing.get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            yield from numeric_leaves(args[0], (*key, 0))
        else:
            for i, a in enumerate(args):
                yield from numeric_leaves(a, (*key, i))


def _plain(obj: Any) -> Any:
    return json.loads(json.dumps(dataclasses.asdict(obj)))


def _flight_base() -> dict[str, Any]:
    """config/flight.yaml with every section written out (None sections: their defaults)."""
    cfg = load_flight_config(REPO / "config" / "flight.yaml")
    cfg = dataclasses.replace(cfg, preprocess=PreprocessConfig(), shield=ShieldConfig())
    base = _plain(cfg)
    base["trigger"] = dict(_plain(MissionTriggerConfig()), mode="socket")
    base["shield"]["seen_level_tol_m"] = 0.3  # an optional number: give it one to replace
    base["shield"]["fence_min_m"] = [-1.0, -1.0, -1.0]  # the optional fence: a box to perturb
    base["shield"]["fence_max_m"] = [5.0, 5.0, 5.0]
    base["shield"]["band_waypoints_m"] = [[0.0, 0.0, 1.2], [2.0, 2.0, 1.2]]  # the optional band
    base["shield"]["band_half_width_m"] = 1.5
    return base


def _set(mapping: dict[str, Any], key: tuple[str | int, ...], value: Any) -> dict[str, Any]:
    out = copy.deepcopy(mapping)
    node: Any = out
    for k in key[:-1]:
        node = node[k]
    node[key[-1]] = value
    return out


def _dotted(key: tuple[str | int, ...]) -> str:
    return ".".join(str(k) for k in key)


def _field(key: tuple[str | int, ...]) -> str:
    """The field's dotted key without tuple indices: ``safety.geofence_max_m``."""
    return ".".join(str(k) for k in key if isinstance(k, str))


def _meaningful(dotted: str, kind: str) -> bool:
    return any(kind == k and fnmatch.fnmatchcase(dotted, pattern) for pattern, k in MEANINGFUL)


def _load_flight(path: Path) -> None:
    """Load as the daemon does: the flight config, then its trigger section (real vehicle)."""
    cfg = load_flight_config(path)
    trigger_config_from_mapping(cfg.trigger, source=str(path), simulated=False)


def _check(dotted: str, field_key: str, kind: str, value: float, source: str, load: Any) -> str | None:
    """None if the value was handled as it must be, else what went wrong."""
    try:
        load()
    except ConfigError as exc:
        msg = str(exc)
        leaf = field_key.rsplit(".", 1)[-1]
        if _meaningful(dotted, kind):
            if f"key '{dotted}': bad value" in msg:
                return f"{dotted}={value!r} is listed as meaningful but its range refuses it: {msg}"
            return None
        named = f"'{field_key}" in msg or (leaf in msg and f"'{field_key.split('.')[0]}" in msg)
        if source not in msg or not named or repr(value) not in msg:
            return f"{dotted}={value!r}: refused without naming file, key and value: {msg}"
        return None
    if not _meaningful(dotted, kind):
        return f"{dotted}={value!r} ({kind}) was accepted and is not listed as meaningful"
    return None


FLIGHT_LEAVES = list(numeric_leaves(FlightConfig)) + [
    (("trigger", *k), t) for k, t in numeric_leaves(MissionTriggerConfig)
]
TRAIN_LEAVES = list(numeric_leaves(TrainConfig))


def test_the_walk_finds_the_fields_of_every_section() -> None:
    """The generated list reaches every section, nested tuples and optional numbers included."""
    found = {_dotted(k) for k, _ in FLIGHT_LEAVES}
    for key in (
        "mission.goal_radius_m", "mission.waypoints_m.0.2", "safety.stale_depth_s",
        "vehicle.connect_timeout_s", "depth.prepare_within_s",
        "odometry.translation_world_m.0", "odometry.rotation_world_from_mocap.2.2", "record.depth_decimation",
        "primitives.scale_m", "primitives.directions.0.0", "preprocess.min_valid_fraction",
        "shield.clearance_m", "shield.seen_level_tol_m", "shield.camera_offset_m.1", "reward.d_floor_m",
        "trigger.client_timeout_s",
    ):
        assert key in found
    assert len(FLIGHT_LEAVES) > 70 and len(TRAIN_LEAVES) > 30


@pytest.mark.parametrize("key", [k for k, _ in FLIGHT_LEAVES], ids=_dotted)
def test_every_numeric_flight_field_refuses_or_means_each_extreme(tmp_path: Path, key: tuple) -> None:
    base = _flight_base()
    path = tmp_path / "flight.yaml"
    problems = []
    for kind, value in VALUES.items():
        path.write_text(yaml.safe_dump(_set(base, key, value)), encoding="utf-8")
        problem = _check(_dotted(key), _field(key), kind, value, str(path), lambda: _load_flight(path))
        if problem:
            problems.append(problem)
    assert not problems, "\n".join(problems)


@pytest.mark.parametrize("key", [k for k, _ in TRAIN_LEAVES], ids=_dotted)
def test_every_numeric_training_field_refuses_or_means_each_extreme(key: tuple) -> None:
    base = TrainConfig().to_dict()
    base["imitation_filter_scales"] = [1.0]  # an empty list by default: give it one to perturb
    source = "run/config.json"
    problems = []
    for kind, value in VALUES.items():
        data = _set(base, key, value)
        dotted = "train." + _dotted(key)
        load = lambda d=data: load_train_config(d, source)  # noqa: E731 - bound per value
        problem = _check(dotted, _field(key), kind, value, source, load)
        if problem:
            problems.append(problem)
    assert not problems, "\n".join(problems)


def test_the_planner_config_walks_to_the_same_sections() -> None:
    """PlannerConfig (what training and flight agree on) nests the sections checked above."""
    keys = {_dotted(k).split(".")[0] for k, _ in numeric_leaves(PlannerConfig)}
    assert keys == {"primitives", "preprocess", "reward"}
    assert parse_config(PlannerConfig, {}) == PlannerConfig()


def test_every_allow_listed_entry_names_a_real_field() -> None:
    """No stale entries: each pattern of MEANINGFUL matches a generated key."""
    keys = {_dotted(k) for k, _ in FLIGHT_LEAVES} | {"train." + _dotted(k) for k, _ in TRAIN_LEAVES}
    for pattern, kind in MEANINGFUL:
        assert kind in VALUES
        assert any(fnmatch.fnmatchcase(k, pattern) for k in keys), pattern
