"""The configuration reference is generated from the config dataclasses and cannot go stale."""

from __future__ import annotations

import dataclasses
import importlib.util
import re
import sys
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Annotated

import pydantic
import pytest
import yaml

from quadnav_onboard.config import parse_config
from quadnav_onboard.config_reference import (
    MissingDocstringError,
    commented_yaml,
    field_docstrings,
    flight_config_yaml,
    markdown_reference,
    missing_docstrings,
    sections,
    type_text,
    unit_of,
)
from quadnav_onboard.daemon.config import FlightConfig
from quadnav_onboard.shield import ShieldConfig

REPO = Path(__file__).resolve().parent.parent


def _load_script() -> ModuleType:
    path = REPO / "scripts" / "gen_config_reference.py"
    spec = importlib.util.spec_from_file_location("gen_config_reference", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


gen = _load_script()


def test_committed_reference_matches_the_code() -> None:
    """docs/configuration.md is exactly what scripts/gen_config_reference.py writes today."""
    committed = (REPO / "docs" / "configuration.md").read_text(encoding="utf-8")
    assert committed == gen.document(), (
        "docs/configuration.md is stale: run python scripts/gen_config_reference.py"
    )


def test_every_flight_and_training_field_has_a_docstring_and_a_row() -> None:
    """Every field of every section of both trees has a docstring and appears as a row."""
    from sim_harness.rl.config import TrainConfig

    assert missing_docstrings(FlightConfig) == []
    assert missing_docstrings(TrainConfig) == []
    doc = gen.document()
    for root in (FlightConfig, TrainConfig):
        for s in sections(root):
            assert [fd.key for fd in s.fields] == [f.name for f in dataclasses.fields(s.cls)]
            for fd in s.fields:
                assert fd.doc and f"| `{fd.key}` |" in doc


@dataclass(frozen=True)
class _Inner:
    documented: float = 1.0
    """A documented field (m)."""
    undocumented_inner: int = 3


@dataclass(frozen=True)
class _Outer:
    speed_m_s: float = 2.0
    """Speed."""
    inner: _Inner = field(default_factory=_Inner)
    """A nested section."""
    undocumented_outer: bool = False


def test_a_field_without_a_docstring_is_refused_by_name() -> None:
    """A config field added without a docstring makes the generator fail, naming class and field,
    however deep it is nested."""
    assert missing_docstrings(_Outer) == [
        f"{__name__}._Outer.undocumented_outer",
        f"{__name__}._Inner.undocumented_inner",
    ]
    with pytest.raises(MissingDocstringError, match=r"undocumented_outer.*undocumented_inner"):
        list(sections(_Outer))
    with pytest.raises(MissingDocstringError):
        markdown_reference([("x", _Outer, "")], "# x")
    with pytest.raises(MissingDocstringError):
        commented_yaml(_Outer)


def test_the_generator_script_fails_on_a_field_without_a_docstring(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The reference test cannot pass with an undocumented field: the script exits 2 naming it."""
    import quadnav_onboard.daemon.config as daemon_config

    monkeypatch.setattr(daemon_config, "FlightConfig", _Outer)
    assert gen.main(["--out", str(tmp_path / "c.md")]) == 2
    assert "undocumented_outer" in capsys.readouterr().err
    assert not (tmp_path / "c.md").exists()


def test_check_mode_tells_a_stale_file(tmp_path: Path) -> None:
    """--check exits 1 on a file that differs from the code and 0 on a fresh one."""
    out = tmp_path / "configuration.md"
    out.write_text("old\n", encoding="utf-8")
    assert gen.main(["--check", "--out", str(out)]) == 1
    assert gen.main(["--out", str(out)]) == 0
    assert gen.main(["--check", "--out", str(out)]) == 0


def test_print_config_yaml_loads_back_into_the_defaults() -> None:
    """The commented YAML of the flight config is valid YAML that validates into FlightConfig()."""
    text = flight_config_yaml()
    assert parse_config(FlightConfig, yaml.safe_load(text), "print-config") == FlightConfig()
    for f in dataclasses.fields(FlightConfig):
        assert re.search(rf"^{f.name}:", text, re.MULTILINE), f.name


def test_the_script_prints_the_commented_yaml(capsys: pytest.CaptureFixture[str]) -> None:
    """--yaml writes the flight config's commented defaults to stdout."""
    assert gen.main(["--yaml"]) == 0
    assert capsys.readouterr().out == flight_config_yaml()


def test_a_null_section_s_commented_keys_uncomment_into_its_defaults() -> None:
    """``shield: null`` is followed by its keys commented out; uncommented they are ShieldConfig()."""
    lines = flight_config_yaml().splitlines()
    start = lines.index("shield: null")
    names = {f.name for f in dataclasses.fields(ShieldConfig)}
    values = []
    for line in lines[start + 2 :]:
        if not line.startswith("  # "):
            break
        m = re.match(r"^  # (\w+): (.*)$", line)
        if m and m.group(1) in names:
            values.append(f"{m.group(1)}: {m.group(2)}")
    data = yaml.safe_load("\n".join(values))
    assert set(data) == names
    assert parse_config(ShieldConfig, data, "shield") == ShieldConfig()


def test_types_ranges_and_units_come_from_the_annotations() -> None:
    """The type column states the annotation's range; the unit comes from the name or the doc."""
    assert type_text(Annotated[float, pydantic.Field(gt=0, le=5)]) == "float in (0, 5]"
    assert type_text(Annotated[int, pydantic.Field(ge=1, le=64)] | None) == "int in [1, 64] | null"
    assert unit_of("speed_m_s", "") == "m/s"
    assert unit_of("stale_depth_s", "") == "s"
    assert unit_of("width", "Frame width (px), in [32, 4096].") == "px"
    assert unit_of("max_steps", "Step limit, in [1, 10 000].") == ""
    assert field_docstrings(_Inner) == {"documented": "A documented field (m)."}
    shield_rows = {fd.key: fd for s in sections(FlightConfig) if s.path == "shield" for fd in s.fields}
    assert shield_rows["clearance_m"].type == "float in (0, 5]"
    assert shield_rows["clearance_m"].default == ShieldConfig().clearance_m


def test_print_config_prints_the_commented_defaults_and_exits_0(capsys) -> None:
    """`quadnav-onboard --print-config` is the generator's YAML, printed before anything else runs."""
    from quadnav_onboard.cli import main
    from quadnav_onboard.config_reference import flight_config_yaml

    assert main(["--print-config"]) == 0
    assert capsys.readouterr().out == flight_config_yaml()
