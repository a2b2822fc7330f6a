"""Procedurally generated training worlds of the paper's families (domain randomisation).

Seven hand-made worlds are few: an agent trained only on them learns *those* worlds (our sweeps:
~80-90 % on Env 1-7, 27-50 % on the held-out Env 8-10). These generators draw new worlds of the
same families -- corridors of varying width, left-right and up-down slaloms, and clutter of poles,
spheres and crates -- from a seeded numpy Generator, as world-file mappings validated by
:func:`sim_harness.world.parse_world`. Each family leaves a gap of at least ``MIN_GAP_M`` for the
quad (radius 0.3 m) by construction, under or over each obstacle of an up-down slalom
(tests/test_procgen.py). Seeds keep the roles apart: the training set (``TrainConfig.procedural_seed``),
the development set of ``quadnav-sim select`` (777) and the test set of ``docs/results.md`` (4242).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from sim_harness.world import World, parse_world

__all__ = ["FAMILIES", "MIN_GAP_M", "procedural_worlds", "random_world"]

FAMILIES = ("corridor", "slalom_lr", "slalom_ud", "clutter")
MIN_GAP_M = 1.6
"""Least free width (m) of any passage: the quad's diameter plus 0.5 m on each side."""
LENGTH_M, ALT_M, HALF_WIDTH_M = 60.0, 2.0, 4.5


def _box(center: tuple[float, float, float], size: tuple[float, float, float], yaw: float = 0.0) -> dict:
    return {"type": "box", "center": [float(c) for c in center], "size": [float(s) for s in size],
            "yaw_deg": float(yaw)}


def _corridor(rng: np.random.Generator, ceiling: float) -> list[dict]:
    out, x = [], 0.0
    while x < LENGTH_M + 2.0:
        seg = float(rng.uniform(8.0, 20.0))
        width = float(rng.uniform(MIN_GAP_M + 0.3, 5.0))
        shift = float(rng.uniform(-0.3, 0.3) * (width - MIN_GAP_M))
        for side in (-1.0, 1.0):
            y = shift + side * (width / 2 + 0.25)
            out.append(_box((x + seg / 2, y, ceiling / 2), (seg, 0.5, ceiling)))
        x += seg
    return out


def _slalom_lr(rng: np.random.Generator, ceiling: float) -> list[dict]:
    out, x, side = [], float(rng.uniform(7.0, 11.0)), float(rng.choice([-1.0, 1.0]))
    while x < LENGTH_M - 3.0:
        reach = float(rng.uniform(0.2, 1.3))  # how far past the path the panel reaches
        thick = float(rng.uniform(0.3, 1.2))
        if rng.random() < 0.3:  # a pole instead of a panel
            r = float(rng.uniform(0.3, 0.8))
            out.append({"type": "cylinder", "center": [x, -side * (reach - r), ceiling / 2], "radius": r,
                        "height": ceiling})
        else:
            y_near, y_far = -side * reach, side * HALF_WIDTH_M
            out.append(_box((x, (y_near + y_far) / 2, ceiling / 2), (thick, abs(y_far - y_near), ceiling)))
        side = -side if rng.random() < 0.85 else side
        x += float(rng.uniform(6.0, 11.0))
    return out


def _slalom_ud(rng: np.random.Generator, ceiling: float) -> list[dict]:
    out, x, up = [], float(rng.uniform(7.0, 11.0)), bool(rng.random() < 0.5)
    while x < LENGTH_M - 3.0:
        # how far past the path it reaches; one that hangs from the ceiling must leave MIN_GAP_M
        # above the floor (the path is only ALT_M up), one standing on the floor MIN_GAP_M below
        # the ceiling (>= 5.5 m: always). One draw either way, so the stream is the same.
        reach = float(rng.uniform(0.2, ALT_M - MIN_GAP_M if up else 1.1))
        thick = float(rng.uniform(0.3, 1.2))
        if up:  # hanging from the ceiling down past the path
            z0, z1 = ALT_M - reach, ceiling
        else:  # standing on the floor up past the path
            z0, z1 = 0.0, ALT_M + reach
        if rng.random() < 0.3:  # a pipe across instead of a panel, reaching as far past the path
            r = float(rng.uniform(0.4, 0.8))
            zc = ALT_M - reach + r if up else ALT_M + reach - r
            out.append({"type": "cylinder", "center": [x, 0.0, zc], "radius": r, "height": 2 * HALF_WIDTH_M,
                        "axis": "y"})
        else:
            out.append(_box((x, 0.0, (z0 + z1) / 2), (thick, 2 * HALF_WIDTH_M, z1 - z0)))
        up = (not up) if rng.random() < 0.85 else up
        x += float(rng.uniform(6.0, 11.0))
    return out


def _clutter(rng: np.random.Generator, ceiling: float) -> list[dict]:
    placed: list[tuple[float, float, float]] = []  # (x, y, radius of the footprint)
    out: list[dict] = []
    for _ in range(int(rng.integers(8, 18)) * 4):
        if len(out) >= 18:
            break
        x, y = float(rng.uniform(6.0, LENGTH_M - 3.0)), float(rng.uniform(-3.0, 3.0))
        kind = rng.choice(["pole", "pole", "sphere", "crate"])
        r = float(rng.uniform(0.3, 1.0 if kind != "sphere" else 1.4))
        if any(np.hypot(x - px, y - py) - r - pr < MIN_GAP_M for px, py, pr in placed):
            continue
        placed.append((x, y, r))
        if kind == "pole":
            out.append({"type": "cylinder", "center": [x, y, ceiling / 2], "radius": r, "height": ceiling})
        elif kind == "sphere":
            z = float(rng.uniform(max(r, ALT_M - r), min(ceiling - r, ALT_M + r)))
            out.append({"type": "sphere", "center": [x, y, z], "radius": r})
        else:
            side = r * np.sqrt(2.0)  # a crate whose footprint fits in the circle of radius r
            out.append(_box((x, y, ceiling / 2), (side, side, ceiling), float(rng.uniform(0, 90))))
    return out


_BUILDERS = {"corridor": _corridor, "slalom_lr": _slalom_lr, "slalom_ud": _slalom_ud, "clutter": _clutter}


def random_world(rng: np.random.Generator, family: str, name: str = "procgen") -> World:
    """One random world of ``family`` (see :data:`FAMILIES`): 60 m straight path at 2 m, 1 m/s."""
    if family not in _BUILDERS:
        raise ValueError(f"unknown world family {family!r}; known: {', '.join(FAMILIES)}")
    ceiling = float(rng.uniform(5.5, 8.0))
    mapping: dict[str, Any] = {
        "name": f"{name}-{family}",
        "path": {"waypoints": [[0.0, 0.0, ALT_M], [LENGTH_M, 0.0, ALT_M]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": ceiling},
        "obstacles": _BUILDERS[family](rng, ceiling),
    }
    return parse_world(mapping, source=f"<procgen {family}>")


def procedural_worlds(n: int, seed: int, families: Sequence[str] = FAMILIES) -> list[World]:
    """``n`` random worlds cycling through ``families`` (a family named twice comes up twice as
    often), reproducible from ``seed``."""
    if not families:
        raise ValueError("procedural_worlds needs at least one family")
    rng = np.random.default_rng(seed)
    return [random_world(rng, families[i % len(families)], name=f"procgen{i:03d}") for i in range(n)]
