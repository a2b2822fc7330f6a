"""Shared test fixtures: a constant "straight ahead" model and short free worlds for flights."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
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


def side_rule_inputs(rng: np.random.Generator, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` network inputs (depth history 1, position history 1) for fits of a rule a network can
    learn: a flat depth image and a random setpoint vector whose y is at least 0.5 m from 0;
    (depth, rel, whether the setpoint is to the left)."""
    depth = np.full((n, 1, 32, 32), 0.5, np.float32)
    rel = rng.normal(size=(n, 1, 3)).astype(np.float32)
    rel[:, 0, 1] = rng.choice([-1.0, 1.0], n) * rng.uniform(0.5, 2.0, n)  # clear of the boundary
    return depth, rel, rel[:, 0, 1] > 0


@pytest.fixture(scope="session")
def side_rule() -> Callable[[np.random.Generator, int], tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """:func:`side_rule_inputs`."""
    return side_rule_inputs


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
