"""quadnav-onboard's command line: bad inputs are refused before anything starts, with a clear message
and no traceback; a dry run prints the paper's row or one JSON object."""

from __future__ import annotations

import json
import random
from pathlib import Path

import pytest
import torch

from quadnav_onboard.checkpoint import save_checkpoint
from quadnav_onboard.cli import main
from quadnav_onboard.daemon.testing import constant_action_checkpoint
from quadnav_onboard.network import DQN, NetworkConfig

WORLD = """name: short
description: a 3 m free path
path: {waypoints: [[0, 0, 1.5], [3, 0, 1.5]], speed_m_s: 1.0}
bounds: {floor_z: 0.0, ceiling_z: 5.0}
obstacles: []
"""


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("m") / "fwd.pt"
    constant_action_checkpoint(str(path), 4)
    return path


def run(capsys: pytest.CaptureFixture[str], *argv: str) -> tuple[int, str, str]:
    code = main(list(argv))
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def test_nothing_to_fly_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    code, _, err = run(capsys, "--log-format", "json")
    assert code == 2 and "--dry-run" in err


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("mission: {speed_m_s: 1.0\n", ["malformed YAML"]),
        ("mission: {max_steps: many}\n", ["mission.max_steps", "'many'"]),
        ("safety: {stale_depth_s: [1]}\n", ["safety.stale_depth_s"]),
    ],
)
def test_bad_config_files_are_refused_naming_file_key_value(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path, text: str, needles: list[str]
) -> None:
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    code, _, err = run(
        capsys, "--dry-run", "--config", str(cfg), "--model", str(model), "--log-format", "json"
    )
    assert code == 2 and str(cfg) in err
    for n in needles:
        assert n in err


def test_a_config_of_random_bytes_is_refused_with_exit_2(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path
) -> None:
    """A binary file is a configuration error (exit 2, which systemd does not restart), not a
    UnicodeDecodeError traceback (exit 1)."""
    cfg = tmp_path / "junk.yaml"
    cfg.write_bytes(random.Random(1).randbytes(2048))
    code, _, err = run(capsys, "--dry-run", "--config", str(cfg), "--model", str(model), "--log-format=json")
    assert code == 2 and f"{cfg}: not a UTF-8 text file" in err


def test_an_empty_config_is_refused_not_flown_on_the_defaults(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path
) -> None:
    """An empty file does not stand for the dataclass defaults: the dry run refuses it."""
    cfg = tmp_path / "empty.yaml"
    cfg.write_text("")
    code, _, err = run(capsys, "--dry-run", "--config", str(cfg), "--model", str(model), "--log-format=json")
    assert code == 2 and f"{cfg}: the file is empty" in err


@pytest.mark.parametrize(("radius", "value"), [(".inf", "inf"), ("9.0", "9.0")])
def test_a_goal_radius_that_fakes_a_success_is_refused_before_arming(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path, radius: str, value: str
) -> None:
    """A goal radius that would be met at the start ("goal_reached after 0 steps", exit 0) is
    refused before arming, naming the file, the key and the value."""
    cfg = tmp_path / "f.yaml"
    cfg.write_text(f"mission: {{waypoints_m: [[0, 0, 1], [5, 0, 1]], goal_radius_m: {radius}}}\n")
    code, _, err = run(capsys, "--dry-run", "--config", str(cfg), "--model", str(model), "--log-format=json")
    assert code == 2 and f"{cfg}: key 'mission.goal_radius_m': bad value {value}" in err


def test_the_goal_radius_is_checked_against_the_dry_runs_world_path(tmp_path: Path) -> None:
    """With the world's path (no waypoints in the config), the flown path is checked before the
    record opens and the vehicle arms: a 3 m world leaves no room for a 2.8 m goal radius."""
    import argparse
    import dataclasses

    from quadnav_onboard.cli import _check_mission_path
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.daemon.config import MissionConfig, default_sim_config
    from sim_harness.world import load_world

    world = tmp_path / "w.yaml"
    world.write_text(WORLD)
    cfg = default_sim_config()
    args = argparse.Namespace(config=None)
    _check_mission_path(args, cfg, load_world(world).path, str(world))
    cfg = dataclasses.replace(cfg, mission=MissionConfig(goal_radius_m=2.8))
    with pytest.raises(ConfigError) as info:
        _check_mission_path(args, cfg, load_world(world).path, str(world))
    msg = str(info.value)
    assert "<embedded defaults/sim.yaml>: key 'mission.goal_radius_m': bad value 2.8" in msg
    assert f"start-to-goal distance 3 m of {world} path.waypoints" in msg


def test_a_real_flight_without_an_explicit_go_is_refused(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    cfg = tmp_path / "f.yaml"
    cfg.write_text("mission: {waypoints_m: [[0, 0, 1], [5, 0, 1]]}\ntrigger: {mode: auto}\n")
    code, _, err = run(capsys, "--config", str(cfg), "--log-format", "json")
    assert code == 2 and "trigger.mode" in err


def test_a_missing_checkpoint_is_refused(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    code, _, err = run(capsys, "--dry-run", "--model", str(tmp_path / "nope.pt"), "--log-format", "json")
    assert code == 2 and "not found" in err and "nope.pt" in err


def test_a_corrupt_checkpoint_is_refused(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x80\x02 this is not a checkpoint" * 10)
    code, _, err = run(capsys, "--dry-run", "--model", str(bad), "--log-format", "json")
    assert code == 2 and "bad.pt" in err and "corrupt" in err


def test_a_model_of_the_wrong_shape_is_refused(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    torch.manual_seed(0)
    path = save_checkpoint(tmp_path / "five.pt", DQN(NetworkConfig(n_actions=5)))
    code, _, err = run(capsys, "--dry-run", "--model", str(path), "--log-format", "json")
    assert code == 2 and "5 outputs" in err and "18" in err


def test_a_missing_world_file_is_refused_without_traceback(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path
) -> None:
    code, _, err = run(
        capsys,
        "--dry-run",
        "--world",
        str(tmp_path / "nowhere.yaml"),
        "--model",
        str(model),
        "--log-format",
        "json",
    )
    assert code == 2 and "nowhere.yaml" in err


@pytest.mark.e2e
def test_dry_run_json_flies_a_world_to_the_goal(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, model: Path
) -> None:
    world = tmp_path / "w.yaml"
    world.write_text(WORLD)
    cfg = tmp_path / "sim.yaml"
    cfg.write_text(
        "mission: {takeoff_speed_m_s: 2.0}\nprimitives: {scale_m: 0.5, duration_s: 0.5}\n"
        "safety: {hold_before_land_s: 0.2}\ndepth: {kind: sim}\nodometry: {kind: sim}\n"
    )
    code, out, _ = run(
        capsys,
        "--dry-run",
        "--config",
        str(cfg),
        "--world",
        str(world),
        "--model",
        str(model),
        "--json",
        "--record-dir",
        str(tmp_path / "rec"),
        "--log-format",
        "json",
    )
    summary = json.loads(out)
    assert code == 0 and summary["stop_reason"] == "goal_reached" and summary["crashed"] is False
    assert summary["navigation_distance_m"] > 2.0 and summary["decision_latency_ms"]["n"] >= 4
    assert len(list((tmp_path / "rec").glob("*.mcap"))) == 1
