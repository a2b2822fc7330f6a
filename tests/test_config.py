"""Typed config loading: errors name file, key path and value."""

import random

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


@pytest.mark.parametrize("text", ["", "# only a comment\n", "\n\n"])
def test_an_empty_file_is_refused_not_read_as_the_defaults(tmp_path, text):
    """A file with no document would silently stand for every default: refused, naming the file;
    an explicit ``{}`` still asks for the defaults."""
    f = tmp_path / "e.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=r"e\.yaml: the file is empty"):
        load_yaml_config(PlannerConfig, f)
    f.write_text("{}\n")
    assert load_yaml_config(PlannerConfig, f) == PlannerConfig()


def test_random_bytes_are_a_config_error_naming_the_file(tmp_path):
    """A binary file (random bytes) is refused as not UTF-8 text, not a UnicodeDecodeError."""
    f = tmp_path / "junk.yaml"
    f.write_bytes(random.Random(0).randbytes(4096))
    with pytest.raises(ConfigError, match=r"junk\.yaml: not a UTF-8 text file"):
        load_yaml_config(PlannerConfig, f)


@pytest.mark.parametrize(
    ("text", "key", "value"),
    [
        ("primitives: {scale_m: .nan}\n", "primitives.scale_m", "nan"),
        ("primitives: {duration_s: .inf}\n", "primitives.duration_s", "inf"),
        ("preprocess: {max_range_m: .nan}\n", "preprocess.max_range_m", "nan"),
        ("reward: {r_upper: -.inf}\n", "reward.r_upper", "-inf"),
    ],
)
def test_nan_and_infinity_are_reported_as_such(tmp_path, text, key, value):
    """NaN is not "less than or equal to 5": the error says the value is not a finite number."""
    f = tmp_path / "p.yaml"
    f.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_yaml_config(PlannerConfig, f)
    assert f"key '{key}': bad value {value}: Input should be a finite number" in str(info.value)


def test_preprocessing_range_must_be_ordered(tmp_path):
    f = tmp_path / "p.yaml"
    f.write_text("preprocess: {min_range_m: 5.0, max_range_m: 4.0}\n")
    with pytest.raises(ConfigError, match=r"min_range_m 5\.0 must be below max_range_m 4\.0"):
        load_yaml_config(PlannerConfig, f)


@pytest.mark.parametrize("word", ["true", "yes", "on", "off"])
def test_a_boolean_for_a_number_is_refused(tmp_path, word):
    """``scale_m: on`` is not 1.0 (pydantic would read YAML's booleans as numbers): refused."""
    f = tmp_path / "p.yaml"
    f.write_text(f"primitives: {{scale_m: {word}}}\n")
    needed = r"key 'primitives\.scale_m': bad value (True|False): a number is needed"
    with pytest.raises(ConfigError, match=needed):
        load_yaml_config(PlannerConfig, f)
