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
            "odometry: {rotation_world_from_mocap: [[1,0,0],[0,1,0],[0,0,2]]}\n",
            ["odometry", "not a rotation"],
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
