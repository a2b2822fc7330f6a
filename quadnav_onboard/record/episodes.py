"""Write a simulated episode (e.g. one trial of ``quadnav-sim eval``) as a flight record.

Sim and flight records share one format, so ``quadnav-review`` reviews both. A sim has no clock
of its own: decision ``k`` is stamped ``t0_mono_s + k * duration_s`` and the trail sample ``j``
``t0_mono_s + j * trail_dt_s``.

Usage from an evaluation loop: collect one :class:`SimStep` per decision of a trial (plus the
quad's trail if the sim keeps it), then call :func:`record_sim_episode` once the trial ends.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.record.recorder import FlightRecorder

__all__ = ["SimStep", "record_sim_episode"]


@dataclass(frozen=True)
class SimStep:
    """One decision of a simulated episode (world frame, x fwd / y left / z up, metres)."""

    action: int
    """Chosen primitive index."""
    pos_world_m: ArrayLike
    """Quad position at the decision, shape (3,)."""
    moving_setpoint_world_m: ArrayLike
    """Moving setpoint at the decision, shape (3,)."""
    rel_pos_body_m: ArrayLike
    """The network's position input (newest), heading frame, shape (3,)."""
    reward: float
    """Reward of the step that followed the decision."""
    progress_m: float
    """Progress along the rough path (m) after the step."""
    deviation_m: float
    """Distance to the rough path (m) after the step."""
    input_32: NDArray[np.float32] | None = None
    """The network's depth input (newest frame), (32, 32) in [0, 1]."""
    q_values: ArrayLike | None = None
    """All Q-values, shape (n_actions,); NaN when the evaluator did not keep them."""
    reward_terms: Mapping[str, Any] = field(default_factory=dict)
    """Anything else worth keeping about the reward (d_prev_m, d_now_m, collided, deviated)."""


def record_sim_episode(
    path: str | Path,
    *,
    steps: Sequence[SimStep],
    stop_reason: str,
    summary: Mapping[str, Any],
    waypoints_world_m: ArrayLike,
    duration_s: float = 1.0,
    metadata: Mapping[str, str] | None = None,
    trail_world_m: ArrayLike | None = None,
    trail_dt_s: float | None = None,
    n_actions: int = 18,
    t0_mono_s: float = 1000.0,
) -> Path:
    """Write one episode to ``path`` and return it.

    ``summary``: the paper's row (see :data:`quadnav_onboard.review.table.SUMMARY_KEYS`).
    ``metadata``: e.g. ``world``, ``world_yaml`` (the world file's YAML: the report draws the
    obstacles), ``model_sha256``, ``seed``, ``trial``. ``trail_world_m`` (T, 3): the quad's path
    sampled every ``trail_dt_s`` seconds from the episode start (drawn as the flown path and used
    for the tracking plot); without it the decision positions stand in.
    """
    meta = {"mode": "sim", "step_duration_s": repr(float(duration_s)), **dict(metadata or {})}
    rec = FlightRecorder(path, metadata=meta, depth_decimation=0, fsync=False)
    try:
        rec.rough_path(t0_mono_s, waypoints_world_m)
        rec.vehicle(t0_mono_s, True, "SIM", {})
        if trail_world_m is not None:
            trail = np.asarray(trail_world_m, dtype=np.float64).reshape(-1, 3)
            dt = float(trail_dt_s) if trail_dt_s else duration_s
            for j, p in enumerate(trail):
                rec.odometry(t0_mono_s + j * dt, p, [1.0, 0.0, 0.0, 0.0])
        else:
            for k, s in enumerate(steps):
                rec.odometry(t0_mono_s + k * duration_s, s.pos_world_m, [1.0, 0.0, 0.0, 0.0])
        for k, s in enumerate(steps):
            t = t0_mono_s + k * duration_s
            if s.input_32 is not None:
                rec.network_input(t, k, s.input_32)
            q = np.full(n_actions, np.nan) if s.q_values is None else s.q_values
            rec.step(
                t,
                step=k,
                action=s.action,
                q_values=q,
                rel_pos_body_m=s.rel_pos_body_m,
                moving_setpoint_world_m=s.moving_setpoint_world_m,
                pos_world_m=s.pos_world_m,
                reward=s.reward,
                reward_terms=s.reward_terms,
                progress_m=s.progress_m,
                deviation_m=s.deviation_m,
                latency_ms=float("nan"),
            )
    finally:
        rec.close(stop_reason, summary, t_mono_s=t0_mono_s + len(steps) * duration_s)
    return Path(path)
