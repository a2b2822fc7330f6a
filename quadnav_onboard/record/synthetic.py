"""A scripted flight written as a flight record: for tests, demos and the report screenshot.

The flight follows the core's semantics (rough path, moving setpoint, C1 chain of Bézier
primitives, the paper's reward) with a scripted "policy" that sidesteps one box obstacle, and a
vehicle that tracks the commanded primitive with a fixed lag (no dynamics). Depth frames show the
box growing as it approaches. Nothing here is a simulator; it only produces plausible data.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from quadnav_onboard.path import RoughPath
from quadnav_onboard.preprocess import preprocess_depth_mm
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.record.recorder import FlightRecorder
from quadnav_onboard.reward import RewardParams, reward

__all__ = ["SYNTHETIC_WORLD", "write_synthetic_flight"]

SYNTHETIC_WORLD: dict[str, Any] = {
    "name": "synthetic-box",
    "description": "a 30 m straight path with one box to sidestep",
    "path": {"waypoints": [[0.0, 0.0, 2.0], [30.0, 0.0, 2.0]], "speed_m_s": 1.0},
    "bounds": {"floor_z": 0.0, "ceiling_z": 6.0},
    "obstacles": [{"type": "box", "center": [12.0, -0.5, 2.0], "size": [1.0, 2.0, 4.0], "yaw_deg": 0.0}],
}
"""The world of the scripted flight, in the sim harness's world-file format."""

_FWD, _LEFT, _RIGHT = (DEFAULT_DIRECTIONS.index(d) for d in ((1, 0, 0), (1, 1, 0), (1, -1, 0)))
_W, _H, _HFOV = 424, 240, math.radians(87.0)


@dataclass(frozen=True)
class _Commanded:
    """A commanded primitive as the recorder draws it (the daemon's ActivePrimitive has these)."""

    primitives: PrimitiveSet
    start_world_m: np.ndarray
    start_vel_world_m_s: np.ndarray
    yaw_rad: float


def _policy(k: int) -> int:
    """Sidestep left before the box (steps 6-8), hold, come back right after it (steps 14-16)."""
    if 6 <= k <= 8:
        return _LEFT
    if 14 <= k <= 16:
        return _RIGHT
    return _FWD


def _depth_frame(pos_world_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A plausible D435-like frame (uint16 mm): open space beyond range, floor, the box nearer."""
    img = np.full((_H, _W), 12000, dtype=np.float64)
    img[int(0.75 * _H) :, :] = 3000.0  # the floor ahead
    box = SYNTHETIC_WORLD["obstacles"][0]
    cx, cy, _ = box["center"]
    dist = cx - box["size"][0] / 2 - pos_world_m[0]
    if 0.2 < dist < 10.0:
        f_px = (_W / 2) / math.tan(_HFOV / 2)
        y_lo, y_hi = cy - box["size"][1] / 2 - pos_world_m[1], cy + box["size"][1] / 2 - pos_world_m[1]
        u_lo = int(np.clip(_W / 2 - y_hi / dist * f_px, 0, _W))
        u_hi = int(np.clip(_W / 2 - y_lo / dist * f_px, 0, _W))
        img[: int(0.75 * _H), u_lo:u_hi] = dist * 1000.0
    img += rng.normal(0.0, 20.0, img.shape)
    img[rng.random(img.shape) < 0.02] = 0.0  # invalid pixels
    return np.clip(img, 0, 65535).astype(np.uint16)


def write_synthetic_flight(
    path: str | Path,
    *,
    n_steps: int = 32,
    crash_at_step: int | None = None,
    seed: int = 0,
    t0_mono_s: float = 1000.0,
    lag_s: float = 0.25,
    depth_hz: float = 10.0,
    odom_hz: float = 20.0,
    depth_decimation: int = 5,
) -> dict[str, Any]:
    """Write a scripted flight of ``n_steps`` 1-s decisions to ``path``; return the summary.

    ``crash_at_step``: stop there with stop reason ``crash``. Returns the summary dict passed to
    ``close`` plus ``stop_reason``.
    """
    rng = np.random.default_rng(seed)
    wps = np.array(SYNTHETIC_WORLD["path"]["waypoints"], dtype=np.float64)
    rough = RoughPath(wps, SYNTHETIC_WORLD["path"]["speed_m_s"])
    prims = PrimitiveSet(scale_m=1.0, duration_s=1.0)
    last = n_steps if crash_at_step is None else min(crash_at_step, n_steps)
    actions = [_policy(k) for k in range(last)]

    # Commanded trajectory: the C1 chain of primitives, sampled at the odometry rate.
    dt = 1.0 / odom_hz
    ts, cmd, vel = [], [], []
    start, v0 = rough.start_m.copy(), np.zeros(3)
    for k, a in enumerate(actions):
        tk = np.arange(0.0, 1.0, dt)
        d, v = prims.sample(a, v0, tk)
        ts.extend(k + tk)
        cmd.extend(start + d)
        vel.extend(v)
        start, v0 = start + prims.end_displacement_m(a), prims.end_velocity_m_s(a)
    ts_a, cmd_a, vel_a = np.array(ts), np.array(cmd), np.array(vel)

    def actual(t: float) -> np.ndarray:
        return np.array([np.interp(t - lag_s, ts_a, cmd_a[:, i], left=cmd_a[0, i]) for i in range(3)])

    meta = {
        "world": SYNTHETIC_WORLD["name"],
        "world_yaml": yaml.safe_dump(SYNTHETIC_WORLD, sort_keys=False),
        "model_sha256": "0" * 64,
        "config_yaml": yaml.safe_dump({"primitives": {"scale_m": 1.0, "duration_s": 1.0}, "seed": seed}),
        "mode": "synthetic",
        "step_duration_s": "1.0",
    }
    params = RewardParams()
    # written far faster than real time: queues that hold the whole flight, so nothing is shed
    n_depth = int(np.ceil(last * depth_hz))
    rec = FlightRecorder(
        path,
        metadata=meta,
        depth_decimation=depth_decimation,
        fsync=False,
        queue_size=16 * (len(ts_a) + last) + 64,
        image_queue_size=max(8, n_depth),
    )
    rec.rough_path(t0_mono_s, wps)
    rec.camera(t0_mono_s, width_px=_W, height_px=_H, hfov_deg=math.degrees(_HFOV), vfov_deg=58.0)
    rec.geofence(t0_mono_s, (-5.0, -10.0, 0.0), (35.0, 10.0, 6.0))
    rec.world(t0_mono_s, SYNTHETIC_WORLD)
    rec.vehicle(t0_mono_s, True, "OFFBOARD", {"local_position_ok": True, "battery_v": 16.4})
    rec.event(t0_mono_s, "mission_start", "mission started", level="info")
    for i, t in enumerate(ts_a):
        p = actual(t)
        rec.odometry(t0_mono_s + t, p + rng.normal(0, 0.01, 3), [1.0, 0.0, 0.0, 0.0], vel_a[i])
        rec.setpoint(t0_mono_s + t, cmd_a[i], vel_a[i], 0.0)
    for t in np.arange(0.0, last, 1.0 / depth_hz):
        rec.depth(t0_mono_s + t, _depth_frame(actual(t), rng))

    total, best = 0.0, 0.0
    start, v0 = rough.start_m.copy(), np.zeros(3)
    for k, a in enumerate(actions):
        pos, pos_next = actual(k), actual(k + 1)
        sp, sp_next = rough.setpoint_at(k), rough.setpoint_at(k + 1)
        crashed = crash_at_step is not None and k == last - 1
        d_prev, d_now = float(np.linalg.norm(sp - pos)), float(np.linalg.norm(sp_next - pos_next))
        r = float(reward(d_prev, d_now, False, crashed, params))
        q = rng.normal(0.0, 0.05, prims.n_actions) + 0.2
        q[a] += 0.4
        progress = float(rough.progress_m(pos))
        best = max(best, progress)
        total += r
        inp = preprocess_depth_mm(_depth_frame(pos, rng))
        t = t0_mono_s + k
        rec.network_input(t, k, inp)
        rec.step(
            t,
            step=k,
            action=a,
            q_values=q,
            rel_pos_body_m=rough.relative_state(sp, pos, 0.0),
            moving_setpoint_world_m=sp,
            pos_world_m=pos,
            reward=r,
            reward_terms={"d_prev_m": d_prev, "d_now_m": d_now, "collided": crashed, "deviated": False},
            progress_m=progress,
            deviation_m=float(rough.deviation_m(pos)),
            latency_ms=float(18.0 + rng.gamma(2.0, 2.0)),
            primitive=_Commanded(prims, start, v0, 0.0),
        )
        start, v0 = start + prims.end_displacement_m(a), prims.end_velocity_m_s(a)
    reached = crash_at_step is None and best >= rough.length_m - 1.0
    reason = "crash" if crash_at_step is not None else ("goal_reached" if reached else "step_limit")
    if crash_at_step is not None:
        rec.event(t0_mono_s + last, "collision", "collision reported", level="error")
        rec.vehicle(t0_mono_s + last, True, "LAND", {"local_position_ok": True, "battery_v": 16.1})
    detail = {"crash": "collision reported", "goal_reached": "within 1.0 m of the goal"}.get(
        reason, "step limit"
    )
    summary = {
        "detail": detail,
        "navigation_distance_m": best,
        "navigation_time_s": float(last),
        "crashed": crash_at_step is not None,
        "total_reward": total,
        "reached_goal": reached,
        "steps": last,
    }
    rec.close(reason, summary, t_mono_s=t0_mono_s + last)
    return {**summary, "stop_reason": reason}
