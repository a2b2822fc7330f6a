"""Typed config loading: errors name file, key path and value."""

import pytest

from quadnav_onboard.config import ConfigError, PlannerConfig, load_yaml_config, parse_config


def test_defaults_are_the_papers():
    cfg = parse_config(PlannerConfig, {})
    assert cfg.primitives.scale_m == 1.0 and cfg.primitives.duration_s == 1.0
    assert len(cfg.primitives.directions) == 18
    assert cfg.reward.r_upper == 0.5 and cfg.reward.max_deviation_m == 5.0
    assert cfg.primitives.build().n_actions == 18


def test_yaml_values_override(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("primitives:\n  scale_m: 0.5\nreward:\n  max_deviation_m: 1.5\n")
    cfg = load_yaml_config(PlannerConfig, f)
    assert cfg.primitives.scale_m == 0.5 and cfg.reward.max_deviation_m == 1.5


def test_config_is_frozen():
    cfg = parse_config(PlannerConfig, {})
    with pytest.raises(AttributeError):
        cfg.primitives.scale_m = 2.0  # type: ignore[misc]


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("primitives:\n  scale_m: -1\n", ["p.yaml", "primitives.scale_m", "-1", "greater than 0"]),
        ("primitives:\n  scale_mm: 1\n", ["p.yaml", "primitives.scale_mm", "unknown key"]),
        ("reward:\n  r_upper: lots\n", ["p.yaml", "reward.r_upper", "'lots'"]),
        ("primitives: [1, 2]\n", ["p.yaml", "primitives"]),
        ("primitives:\n  scale_m: 1\n  scale_m: 2\n", ["p.yaml", "duplicate key 'scale_m'"]),
        ("primitives: {scale_m: 1\n", ["p.yaml", "malformed YAML"]),
        ("- 1\n- 2\n", ["p.yaml", "mapping at the top level"]),
    ],
)
def test_bad_files_name_file_key_and_value(tmp_path, text, needles):
    f = tmp_path / "p.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_yaml_config(PlannerConfig, f)
    for needle in needles:
        assert needle in str(info.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot read"):
        load_yaml_config(PlannerConfig, tmp_path / "absent.yaml")


def test_empty_file_gives_defaults(tmp_path):
    f = tmp_path / "e.yaml"
    f.write_text("")
    assert load_yaml_config(PlannerConfig, f) == PlannerConfig()
