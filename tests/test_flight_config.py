"""Flight configuration: the shipped files load; bad files are refused naming file, key and value."""

from __future__ import annotations

from pathlib import Path

import pytest

from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.config import FlightConfig, default_sim_config, load_flight_config

REPO = Path(__file__).resolve().parents[1]


def test_the_lab_config_has_the_papers_real_flight_settings() -> None:
    cfg = load_flight_config(REPO / "config" / "flight.yaml")
    assert cfg.mission.speed_m_s == 0.5 and cfg.mission.max_steps == 30
    assert cfg.primitives is not None and cfg.primitives.scale_m == 0.5
    assert (
        cfg.depth.kind == "uvc" and cfg.odometry.kind == "mocap" and cfg.vehicle.url.startswith("serial://")
    )


def test_the_sim_config_equals_the_embedded_default() -> None:
    assert load_flight_config(REPO / "config" / "sim.yaml", require_waypoints=False) == default_sim_config()


def test_defaults_construct_without_a_file() -> None:
    cfg = FlightConfig()
    assert cfg.safety.stale_depth_s == 0.3 and cfg.safety.stale_odometry_s == 0.1
    assert cfg.vehicle.setpoint_rate_hz == 20.0


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("mission: {speed_m_s: fast}\n", ["mission.speed_m_s", "'fast'"]),
        ("mission: {max_steps: 0}\n", ["mission.max_steps", "0"]),
        ("safety: {stale_depth_s: -1}\n", ["safety.stale_depth_s", "-1"]),
        ("vehicle: {urll: x}\n", ["vehicle.urll", "unknown key"]),
        ("depth: {kind: kinect}\n", ["depth.kind", "kinect"]),
        (
            "odometry: {rotation_world_from_mocap: [[1,0,0],[0,1,0],[0,0,-1]]}\n",
            ["odometry", "not a rotation"],
        ),
        (
            "odometry: {rotation_world_from_mocap: [[1,0,0],[0,1,0],[0,0,2]]}\n",
            ["odometry.rotation_world_from_mocap.2.2", "2", "less than or equal to 1"],
        ),
        ("mission: {waypoints_m: [[0, 0, 1]]}\n", ["mission.waypoints_m", "2 waypoints"]),
        ("mission: {speed_m_s: 1.0\n", ["malformed YAML"]),
        ("- just\n- a list\n", ["mapping"]),
    ],
)
def test_bad_config_files_name_file_key_and_value(tmp_path: Path, text: str, needles: list[str]) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_flight_config(path, require_waypoints=False)
    msg = str(info.value)
    assert str(path) in msg
    for needle in needles:
        assert needle in msg


def test_a_real_flight_needs_waypoints(tmp_path: Path) -> None:
    path = tmp_path / "f.yaml"
    path.write_text("mission: {speed_m_s: 0.5}\n")
    with pytest.raises(ConfigError, match=r"mission\.waypoints_m"):
        load_flight_config(path)


def test_the_preparation_window_spans_at_least_one_and_a_half_frames() -> None:
    """depth.prepare_within_s as configured at 30 fps; widened to 1.5 frame periods for a slow
    camera (so a frame normally arrives inside it); null stays null (every frame prepared)."""
    from quadnav_onboard.daemon.config import DepthSourceConfig

    assert DepthSourceConfig().preparation_window_s() == 0.1
    assert DepthSourceConfig(fps=6.0).preparation_window_s() == 0.25
    assert DepthSourceConfig(prepare_within_s=None).preparation_window_s() is None


def _lab_config_with(tmp_path: Path, section: str, key: str, value: object) -> Path:
    """config/flight.yaml with one key of one section replaced, written to a temporary file."""
    import yaml

    data = yaml.safe_load((REPO / "config" / "flight.yaml").read_text(encoding="utf-8"))
    data[section] = dict(data.get(section) or {}, **{key: value})
    path = tmp_path / "flight.yaml"
    path.write_text(yaml.safe_dump(data), encoding="utf-8")
    return path


_LIMITS = [
    ("safety", k)
    for k in (
        "stale_depth_s", "stale_odometry_s", "link_timeout_s", "inference_budget_s", "max_deviation_m",
        "altitude_ceiling_m", "hold_before_land_s", "land_timeout_s",
    )
] + [("mission", k) for k in ("start_tolerance_m", "takeoff_timeout_s", "goal_radius_m")] + [
    ("vehicle", k) for k in ("connect_timeout_s", "command_timeout_s", "health_timeout_s")
] + [("depth", "prepare_within_s")]


@pytest.mark.parametrize(("section", "key"), _LIMITS)
@pytest.mark.parametrize("value", [float("inf"), 1e12])
def test_an_infinite_or_absurd_limit_is_refused(tmp_path: Path, section: str, key: str, value: float) -> None:
    """A limit of .inf or 1e12 would switch its check off: refused, naming the file, the key and
    the value."""
    path = _lab_config_with(tmp_path, section, key, value)
    with pytest.raises(ConfigError) as info:
        load_flight_config(path)
    assert f"{path}: key '{section}.{key}': bad value {value!r}" in str(info.value)


def test_nan_is_reported_as_nan_not_as_out_of_range(tmp_path: Path) -> None:
    path = _lab_config_with(tmp_path, "mission", "speed_m_s", float("nan"))
    with pytest.raises(ConfigError) as info:
        load_flight_config(path)
    assert "key 'mission.speed_m_s': bad value nan: Input should be a finite number" in str(info.value)
    assert "less than" not in str(info.value)


def test_a_nan_mocap_origin_is_refused(tmp_path: Path) -> None:
    path = _lab_config_with(tmp_path, "odometry", "translation_world_m", [float("nan")] * 3)
    with pytest.raises(ConfigError, match=r"key 'odometry\.translation_world_m\.0': bad value nan"):
        load_flight_config(path)


@pytest.mark.parametrize("radius", [3.5, 3.4, 3.31])
def test_a_goal_radius_reaching_back_to_the_start_is_refused(tmp_path: Path, radius: float) -> None:
    """The lab path is 3.5 m long and the start tolerance 0.2 m: a goal radius of 3.3 m or more would
    be met at the start ("goal reached after 0 steps"), so it is refused naming file, key and value."""
    path = _lab_config_with(tmp_path, "mission", "goal_radius_m", radius)
    with pytest.raises(ConfigError) as info:
        load_flight_config(path)
    msg = str(info.value)
    assert f"{path}: key 'mission.goal_radius_m': bad value {radius!r}" in msg
    assert "start-to-goal distance 3.5 m" in msg


def test_a_goal_radius_short_of_the_start_is_accepted(tmp_path: Path) -> None:
    path = _lab_config_with(tmp_path, "mission", "goal_radius_m", 3.0)
    assert load_flight_config(path).mission.goal_radius_m == 3.0


@pytest.mark.parametrize(
    ("waypoints", "needles"),
    [
        ([[0, 0, 1.2], [2, 2, 3.5]], ["mission.waypoints_m[1] [2.0, 2.0, 3.5]", "geofence"]),
        ([[0, 0, 1.2], [2, 2, 0.3]], ["mission.waypoints_m[1] [2.0, 2.0, 0.3]", "altitude band"]),
        ([[0, 0, 1.2], [0, 0, 1.2], [2, 2, 1.2]], ["mission.waypoints_m", "[0] and [1] are both"]),
        ([[0, 0, 1.2], [2, 2, 1e9]], ["mission.waypoints_m.1.2", "1000000000.0"]),
    ],
)
def test_bad_waypoints_name_the_file_the_key_and_the_waypoint(
    tmp_path: Path, waypoints: list, needles: list[str]
) -> None:
    path = _lab_config_with(tmp_path, "mission", "waypoints_m", waypoints)
    with pytest.raises(ConfigError) as info:
        load_flight_config(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}: ")
    for needle in needles:
        assert needle in msg


def test_an_empty_flight_file_is_refused(tmp_path: Path) -> None:
    """An empty file does not stand for the dataclass defaults: refused, naming the file."""
    path = tmp_path / "empty.yaml"
    path.write_text("")
    with pytest.raises(ConfigError, match=r"empty\.yaml: the file is empty"):
        load_flight_config(path, require_waypoints=False)
