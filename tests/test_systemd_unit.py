"""The systemd unit verifies cleanly, scores <= 2.0 exposure, and encodes the flight-safety lifecycle."""

from __future__ import annotations

import importlib.util
import re
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

REPO = Path(__file__).resolve().parent.parent
UNIT = REPO / "systemd" / "quadnav.service"
RULES = REPO / "systemd" / "99-quadnav.rules"
SCRIPT = REPO / "scripts" / "check_systemd_unit.py"


def _load_script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("check_systemd_unit", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


check = _load_script()


def _keys(text: str) -> dict[str, list[str]]:
    """Unit file keys -> all their values (systemd allows repeated keys)."""
    out: dict[str, list[str]] = {}
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith(("#", ";", "[")) and "=" in line:
            key, value = line.split("=", 1)
            out.setdefault(key.strip(), []).append(value.strip())
    return out


def _timespan_s(value: str) -> float:
    m = re.fullmatch(r"([0-9.]+)\s*(ms|s|min)?", value)
    assert m, value
    return float(m.group(1)) * {"ms": 1e-3, "s": 1.0, "min": 60.0, None: 1.0}[m.group(2)]


def test_check_script_passes_on_the_shipped_unit() -> None:
    """The CI script (as a subprocess) verifies the unit with no warnings and scores it <= 2.0."""
    proc = subprocess.run(
        [sys.executable, str(SCRIPT), "--json"], capture_output=True, text=True, timeout=60, check=False
    )
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '"ok": true' in proc.stdout
    assert check.exposure_score(UNIT) <= 2.0


def test_check_script_fails_a_weak_unit(tmp_path: Path) -> None:
    """An unhardened unit scores above 2.0 and the script exits 1 naming the score."""
    weak = tmp_path / "weak.service"
    weak.write_text("[Unit]\nDescription=weak\n[Service]\nExecStart=/usr/bin/quadnav-onboard\n")
    assert check.exposure_score(weak) > 2.0
    result = check.check_unit(weak, exec_path=Path(sys.executable))
    assert not result.ok
    assert any(p.startswith("security: exposure") for p in result.problems)
    assert check.main(["--unit", str(weak), "--exec", sys.executable]) == 1


def test_check_script_fails_on_a_typo_that_systemd_only_warns_about(tmp_path: Path) -> None:
    """A misspelt hardening key (silently ignored by systemd) is a failure, reported with its line."""
    bad = tmp_path / "quadnav.service"
    bad.write_text(UNIT.read_text().replace("NoNewPrivileges=yes", "NoNewPrivilege=yes"))
    problems = check.verify_problems(bad, Path(sys.executable))
    assert any("Unknown key" in p and "NoNewPrivilege" in p for p in problems), problems


def test_check_script_reports_missing_unit_cleanly(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A wrong --unit path gives exit 2 and a one-line message, not a traceback."""
    assert check.main(["--unit", str(tmp_path / "nope.service")]) == 2
    assert "no such unit file" in capsys.readouterr().err


def test_snippets_create_the_quadnav_user_and_config_folder() -> None:
    """sysusers creates user quadnav; tmpfiles creates /etc/quadnav (applied in a temporary root)."""
    sysusers = UNIT.with_suffix(".sysusers.conf")
    tmpfiles = UNIT.with_suffix(".tmpfiles.conf")
    assert check.snippet_problems(sysusers, tmpfiles) == []


def test_unit_lifecycle_is_notify_with_a_watchdog_and_no_restart_into_flight() -> None:
    """Type=notify, a 4-15 s watchdog (> 2 x the 1 s step, bounded hang), restart only on failure, capped."""
    keys = _keys(UNIT.read_text())
    assert keys["Type"] == ["notify"]
    assert keys["NotifyAccess"] == ["main"]
    assert 4.0 <= _timespan_s(keys["WatchdogSec"][0]) <= 15.0
    assert keys["Restart"] == ["on-failure"]
    # quadnav_onboard.daemon.supervisor.ExitCode: 2 refused, 3 safe abort, 4 crash: no restart
    assert set(keys["RestartPreventExitStatus"][0].split()) == {"2", "3", "4"}
    assert int(keys["StartLimitBurst"][0]) <= 3
    assert keys["ExecStart"][0].endswith("quadnav-onboard --config /etc/quadnav/flight.yaml")
    assert "--dry-run" not in keys["ExecStart"][0]


def test_unit_runs_unprivileged_with_only_camera_and_serial_devices() -> None:
    """User quadnav, no capabilities, closed device policy allowing only V4L2 and serial ttys."""
    keys = _keys(UNIT.read_text())
    assert keys["User"] == ["quadnav"] and keys["Group"] == ["quadnav"]
    assert keys["CapabilityBoundingSet"] == [""]
    assert keys["NoNewPrivileges"] == ["yes"]
    assert keys["DevicePolicy"] == ["closed"]
    allowed = {v.split()[0] for v in keys["DeviceAllow"]}
    assert allowed == {"char-video4linux", "char-ttyACM", "char-ttyUSB", "char-ttyTHS"}
    assert "SupplementaryGroups" not in keys  # no broad video/dialout membership
    assert keys["IPAddressDeny"] == ["any"]


def _rules() -> list[dict[str, str]]:
    rules = []
    for line in RULES.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith("#"):
            pairs = re.findall(r'([A-Z_]+(?:\{[^}]+\})?)(==|\+=|=)"([^"]*)"', line)
            assert pairs, f"unparsable rule: {line}"
            assert len(pairs) == line.count('"') // 2, f"stray text in rule: {line}"
            rules.append({k + ("==" if op == "==" else ""): v for k, op, v in pairs})
    return rules


def test_udev_rule_gives_group_quadnav_the_d435_and_flight_controller_only() -> None:
    """Every rule assigns group quadnav mode 0660; the D435 (8086:0b07) and a PX4 tty are covered."""
    rules = _rules()
    assert all(r.get("GROUP") == "quadnav" and r.get("MODE") == "0660" for r in rules)
    d435 = [
        r for r in rules if r.get("ATTRS{idVendor}==") == "8086" and r.get("ATTRS{idProduct}==") == "0b07"
    ]
    assert d435 and d435[0].get("SUBSYSTEM==") == "video4linux"
    assert any(r.get("SUBSYSTEM==") == "tty" and r.get("ATTRS{idVendor}==") == "26ac" for r in rules)
    assert {r.get("SUBSYSTEM==", "tty") for r in rules} <= {"video4linux", "tty"}
