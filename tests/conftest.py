"""Shared test fixtures: a constant "straight ahead" model and short free worlds for flights."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from quadnav_onboard.daemon.testing import constant_action_checkpoint

FORWARD = 4
"""The action index of "straight ahead" in the 18-primitive set."""


def write_straight_world(directory: Path, length_m: float, height_m: float = 1.5) -> Path:
    """A free world whose rough path runs ``length_m`` along x at ``height_m``; its file."""
    path = directory / f"straight-{length_m:g}m.yaml"
    path.write_text(
        f"name: straight-{length_m:g}m\n"
        f"description: a {length_m:g} m free path for tests\n"
        f"path:\n  waypoints: [[0, 0, {height_m}], [{length_m}, 0, {height_m}]]\n  speed_m_s: 1.0\n"
        "bounds: {floor_z: 0.0, ceiling_z: 5.0}\nobstacles: []\n"
    )
    return path


@pytest.fixture(scope="session")
def straight_world() -> Callable[[Path, float], Path]:
    """:func:`write_straight_world`, for module-scoped world fixtures."""
    return write_straight_world


@pytest.fixture(scope="module")
def forward_model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A checkpoint that always picks "straight ahead" (the trained model is not the subject)."""
    path = tmp_path_factory.mktemp("m") / "fwd.pt"
    constant_action_checkpoint(str(path), FORWARD)
    return path


@pytest.fixture
def one_torch_thread():
    """torch held to one thread for the test: two OpenMP threads on a shared 2-core machine are
    many times slower than one. Modules that train use it for every test
    (``pytestmark = pytest.mark.usefixtures("one_torch_thread")``)."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
