"""Hardware tests: each is skipped unless its device address is given in the environment."""

from __future__ import annotations

import os

import pytest


def require_env(name: str, what: str) -> str:
    """The value of ``name``, or skip the test saying which device it needs."""
    value = os.environ.get(name, "").strip()
    if not value:
        pytest.skip(f"{what}: set {name} to run (see sys_test/README.md)")
    return value
