"""What the package asks the installer for, and how the daemon behaves when the optional motion-capture
library is missing: ``odometry.kind: mocap`` is refused before anything connects, naming the extra;
every other configuration works without it."""

from __future__ import annotations

import re
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from quadnav_onboard.cli import main
from quadnav_onboard.config import ConfigError
from quadnav_onboard.daemon.config import OdometrySourceConfig, load_flight_config
from quadnav_onboard.daemon.hardware import hardware_parts, require_motioncapture
from quadnav_onboard.vehicle import MavsdkVehicle

if sys.version_info >= (3, 11):
    import tomllib
else:  # pytest itself depends on tomli before 3.11
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent
FLIGHT_YAML = REPO / "config" / "flight.yaml"


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text())


def _names(requirements: list[str]) -> dict[str, str]:
    """{distribution name (lower case): its version specifier}."""
    out = {}
    for req in requirements:
        m = re.match(r"\s*([A-Za-z0-9_.-]+)\s*(.*)", req)
        assert m is not None, req
        out[m.group(1).lower()] = m.group(2).strip()
    return out


@pytest.fixture
def no_motioncapture(monkeypatch: pytest.MonkeyPatch) -> None:
    """The motioncapture library cannot be imported (what an install without the extra looks like)."""
    monkeypatch.setitem(sys.modules, "motioncapture", None)
    with pytest.raises(ImportError):
        import motioncapture  # noqa: F401


def test_motioncapture_is_an_extra_and_not_a_runtime_dependency() -> None:
    """A plain install never pulls motioncapture (no ARM64 wheel); `quadnav[mocap]` does."""
    project = _pyproject()["project"]
    assert "motioncapture" not in _names(project["dependencies"])
    assert "motioncapture" in _names(project["optional-dependencies"]["mocap"])


def test_build_backend_and_exact_pins() -> None:
    """setuptools >= 77 (SPDX license string), and mavsdk pinned exactly (its offboard plugin object
    is used directly by the setpoint path)."""
    pyproject = _pyproject()
    assert "setuptools>=77" in pyproject["build-system"]["requires"]
    assert pyproject["project"]["license"] == "BSD-3-Clause"
    assert _names(pyproject["project"]["dependencies"])["mavsdk"].startswith("==")


def test_makefile_installs_the_mocap_extra_for_the_dry_run() -> None:
    """`make install` / `make install-dev` install the extra (the dry run reads an emulated NatNet
    server through the real motioncapture library)."""
    makefile = (REPO / "Makefile").read_text()
    assert re.search(r"^\s*\$\(PIP\) install -q -e \"?\.\[mocap\]\"?\s*$", makefile, re.MULTILINE)
    assert re.search(r"^\s*\$\(PIP\) install -q -e \"?\.\[dev,mocap\]\"?\s*$", makefile, re.MULTILINE)


def test_the_check_refuses_without_the_library_naming_the_extra(no_motioncapture: None) -> None:
    """The refusal is a ConfigError naming the file, the key, the value and the install command."""
    with pytest.raises(ConfigError) as err:
        require_motioncapture("flight.yaml")
    msg = str(err.value)
    assert msg.startswith("flight.yaml: key 'odometry.kind': value 'mocap'")
    assert "pip install 'quadnav[mocap]'" in msg


def test_the_check_passes_with_the_library_installed() -> None:
    """In this environment (the dev install has the extra) the check finds motioncapture."""
    require_motioncapture("flight.yaml")


def test_mocap_odometry_without_the_library_is_refused_by_the_wiring(no_motioncapture: None) -> None:
    """hardware_parts refuses the lab config (kind: mocap) before building any source."""
    cfg = load_flight_config(FLIGHT_YAML)
    assert cfg.odometry.kind == "mocap"
    with pytest.raises(ConfigError, match=re.escape("quadnav[mocap]")):
        hardware_parts(cfg, str(FLIGHT_YAML))


def test_px4_odometry_needs_no_motioncapture(no_motioncapture: None) -> None:
    """A lab flying on PX4's own estimate gets all its parts without the extra."""
    cfg = load_flight_config(FLIGHT_YAML)
    cfg = replace(cfg, odometry=OdometrySourceConfig(kind="px4"))
    parts = hardware_parts(cfg, str(FLIGHT_YAML))
    assert type(parts["odometry"]).__name__ == "Px4OdometrySource"


def test_daemon_exits_2_before_connecting_when_the_extra_is_missing(
    no_motioncapture: None, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """`quadnav-onboard --config flight.yaml` (kind: mocap) exits 2, "refused before arming", with the
    install command on stderr and without ever opening the vehicle link."""
    connects: list[object] = []

    async def connect(self: MavsdkVehicle) -> None:
        connects.append(self)

    monkeypatch.setattr(MavsdkVehicle, "connect", connect)
    code = main(["--config", str(FLIGHT_YAML), "--no-record", "--log-format", "json"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "pip install 'quadnav[mocap]'" in err and "odometry.kind" in err
    assert "Traceback" not in err
    assert connects == []


def _target_deps_script():  # scripts/ is not a package
    import importlib.util as ilu

    spec = ilu.spec_from_file_location("check_target_deps", REPO / "scripts" / "check_target_deps.py")
    assert spec is not None and spec.loader is not None
    module = ilu.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_target_check_resolves_the_runtime_set_with_the_makefile_torch() -> None:
    """The ARM64 check asks for every runtime dependency but motioncapture, and CI's torch pin."""
    script = _target_deps_script()
    reqs = script.runtime_requirements(REPO / "pyproject.toml")
    assert set(_names(reqs)) == set(_names(_pyproject()["project"]["dependencies"])) - {"motioncapture"}
    assert script.torch_pin(REPO / "Makefile") == "torch==2.13.0"


def test_target_check_platforms_and_wheel_tags() -> None:
    """glibc 2.35 admits manylinux2014 and 2_17..2_35 wheels for aarch64; an x86-64 or source file is
    not a wheel for the target."""
    script = _target_deps_script()
    tags = script.platform_tags("aarch64", "2.35")
    assert tags[0] == "manylinux2014_aarch64" and tags[1] == "manylinux_2_17_aarch64"
    assert tags[-1] == "manylinux_2_35_aarch64" and len(tags) == 1 + 19
    ok = script.wheel_is_for_target
    assert ok("torch-2.13.0-cp310-cp310-manylinux_2_28_aarch64.whl", "aarch64")
    assert ok("numpy-2.2.6-cp310-cp310-manylinux_2_17_aarch64.manylinux2014_aarch64.whl", "aarch64")
    assert ok("structlog-26.1.0-py3-none-any.whl", "aarch64")
    assert not ok("motioncapture-1.1-cp310-cp310-manylinux_2_28_x86_64.whl", "aarch64")
    assert not ok("motioncapture-1.1.tar.gz", "aarch64")
    with pytest.raises(SystemExit, match=r"2\.N"):
        script.platform_tags("aarch64", "2.5")


def test_the_setpoint_path_matches_the_pinned_mavsdk() -> None:
    """The pin in pyproject.toml, the installed mavsdk and the version the setpoint path is written
    for agree, and that release's OffboardAsync does hold the synchronous plugin as ``_plugin``."""
    import inspect
    from importlib.metadata import version

    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.plugins.offboard import Offboard

    from quadnav_onboard.vehicle import MAVSDK_VERSION

    assert _names(_pyproject()["project"]["dependencies"])["mavsdk"] == f"=={MAVSDK_VERSION}"
    assert version("mavsdk") == MAVSDK_VERSION
    assert "self._plugin = Offboard(" in inspect.getsource(OffboardAsync.__init__)
    assert callable(Offboard.set_position_velocity_ned)


def test_a_mavsdk_without_the_plugin_object_is_refused_at_connect() -> None:
    """An OffboardAsync without ``_plugin`` (another MAVSDK release) is refused with a VehicleError
    naming the release quadnav needs; one with it hands back the plugin's own method."""
    from unittest import mock

    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.plugins.offboard import Offboard

    from quadnav_onboard.vehicle import VehicleError, VehicleErrorKind, _sync_setpoint_sender

    other_release = mock.create_autospec(OffboardAsync, instance=True)  # no instance attributes
    with pytest.raises(VehicleError, match=re.escape("pip install 'mavsdk==4.1.0'")) as err:
        _sync_setpoint_sender(other_release)
    assert err.value.kind is VehicleErrorKind.CONNECT
    this_release = mock.create_autospec(OffboardAsync, instance=True)
    this_release._plugin = mock.create_autospec(Offboard, instance=True)
    assert _sync_setpoint_sender(this_release) is this_release._plugin.set_position_velocity_ned
