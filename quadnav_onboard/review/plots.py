"""The report's figures about where the flight went: trajectory over the world, tracking, overlay.

:mod:`plots_decisions` has the figures about what it saw and chose, and its timeline.

Each function takes a :class:`~quadnav_onboard.record.reader.FlightRecord` and returns a
matplotlib Figure (Agg, no display). Times on the axes are seconds since the flight's first
decision; positions are world frame (x forward, y left, z up), metres.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import yaml
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle
from numpy.typing import NDArray

from quadnav_onboard.record.reader import FlightRecord

__all__ = [
    "estimate_lag_s",
    "fig_overlay",
    "fig_tracking",
    "fig_trajectory",
    "legend",
    "t_zero",
    "world_of",
]

plt.rcParams.update({"font.size": 10, "axes.grid": True, "grid.alpha": 0.3, "figure.dpi": 100})
_OBST = {"facecolor": "#9aa4b1", "edgecolor": "#4a5361", "alpha": 0.6, "lw": 1}


def legend(ax: Any, **kw: Any) -> None:
    """A legend only when something is labelled (an empty one warns)."""
    if ax.get_legend_handles_labels()[0]:
        ax.legend(**kw)


def t_zero(rec: FlightRecord) -> float:
    """Time origin (monotonic s) of the plots: the first decision, else the first odometry."""
    if rec.steps:
        return float(rec.steps[0]["t_mono_s"])
    if len(rec.odom_t_s):
        return float(rec.odom_t_s[0])
    return 0.0


def world_of(rec: FlightRecord) -> dict[str, Any] | None:
    """The world (sim-harness world-file mapping): metadata ``world_yaml``, else the file ``world`` names."""
    text = rec.info.get("world_yaml")
    if not text:  # older records name the world file; use it if it is on this machine
        ref = rec.info.get("world", "")
        if not ref.endswith((".yaml", ".yml")) or not Path(ref).is_file():
            return None
        try:
            text = Path(ref).read_text(encoding="utf-8")
        except OSError:
            return None
    try:
        world = yaml.safe_load(text)
    except yaml.YAMLError:
        return None
    return world if isinstance(world, dict) else None


def _path_of(rec: FlightRecord, world: dict[str, Any] | None) -> NDArray[np.float64] | None:
    if rec.path_waypoints_m is not None:
        return rec.path_waypoints_m
    try:
        return np.asarray(world["path"]["waypoints"], dtype=np.float64).reshape(-1, 3)  # type: ignore[index]
    except (TypeError, KeyError, ValueError):
        return None


def _draw_obstacles(ax: Any, world: dict[str, Any] | None, view: str) -> None:
    """Footprints of boxes, spheres and cylinders; ``view`` "top" (x-y) or "side" (x-z)."""
    if not world:
        return
    j = 1 if view == "top" else 2
    for ob in world.get("obstacles") or []:
        try:
            c = np.asarray(ob["center"], dtype=np.float64)
            kind = ob.get("type")
            if kind == "sphere":
                ax.add_patch(Circle((c[0], c[j]), float(ob["radius"]), **_OBST))
            elif kind == "box":
                half = np.asarray(ob["size"], dtype=np.float64) / 2
                yaw = math.radians(float(ob.get("yaw_deg", 0.0)))
                if view == "top":
                    rot = np.array([[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]])
                    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half[:2]
                    ax.add_patch(Polygon(corners @ rot.T + c[:2], closed=True, **_OBST))
                else:
                    hx = abs(math.cos(yaw)) * half[0] + abs(math.sin(yaw)) * half[1]
                    ax.add_patch(Rectangle((c[0] - hx, c[2] - half[2]), 2 * hx, 2 * half[2], **_OBST))
            elif kind == "cylinder":
                r, h, axis = float(ob["radius"]), float(ob["height"]) / 2, ob.get("axis", "z")
                axis_j = {"x": 0, "y": 1, "z": 2}[axis]
                if axis_j not in (0, j):  # seen end-on: a circle
                    ax.add_patch(Circle((c[0], c[j]), r, **_OBST))
                else:
                    ext = [r, r]
                    ext[0 if axis_j == 0 else 1] = h
                    ax.add_patch(Rectangle((c[0] - ext[0], c[j] - ext[1]), 2 * ext[0], 2 * ext[1], **_OBST))
        except (KeyError, TypeError, ValueError):
            continue


def fig_trajectory(rec: FlightRecord) -> Figure:
    """Top (x-y) and side (x-z) views: world, rough path, moving setpoint, commanded and flown path."""
    world = world_of(rec)
    wps = _path_of(rec, world)
    fig, axes = plt.subplots(2, 1, figsize=(11, 7.5), constrained_layout=True)
    for ax, view in zip(axes, ("top", "side"), strict=True):
        j = 1 if view == "top" else 2
        _draw_obstacles(ax, world, view)
        if view == "side" and world and world.get("bounds"):
            b = world["bounds"]
            for key, label in (("floor_z", "floor"), ("ceiling_z", "ceiling")):
                if b.get(key) is not None:
                    ax.axhline(float(b[key]), color="#6b4f2a", lw=2, alpha=0.6, label=label)
        if wps is not None:
            ax.plot(wps[:, 0], wps[:, j], "--", color="#555", lw=1.5, label="rough path")
        if len(rec.setpoint_t_s):
            sp = rec.setpoint_pos_world_m
            ax.plot(sp[:, 0], sp[:, j], color="#f28e2b", lw=1.2, label="commanded setpoint")
        if len(rec.odom_t_s):
            p = rec.odom_pos_world_m
            ax.plot(p[:, 0], p[:, j], color="#1f77b4", lw=2.2, label="flown (odometry)")
            ax.plot(p[0, 0], p[0, j], "o", color="#2ca02c", ms=8, label="start")
            end_style = "X" if _crashed(rec) else "s"
            ax.plot(p[-1, 0], p[-1, j], end_style, color="#d62728", ms=10, label="end")
        if rec.steps:
            ms = rec.step_array("moving_setpoint_world_m")
            pos = rec.step_array("pos_world_m")
            ax.plot(ms[:, 0], ms[:, j], ".", color="#9467bd", ms=6, label="moving setpoint (per step)")
            ax.plot(pos[:, 0], pos[:, j], "|", color="#1f77b4", ms=8, label="decision points")
        ax.set_xlabel("x (m, forward)")
        ax.set_ylabel("y (m, left)" if view == "top" else "z (m, up)")
        ax.set_title("Top view" if view == "top" else "Side view")
        ax.set_aspect("equal", adjustable="datalim")
    legend(axes[0], loc="upper left", fontsize=8, ncol=4, framealpha=0.9)
    return fig


def _crashed(rec: FlightRecord) -> bool:
    reason = str((rec.stop or {}).get("stop_reason", "")).lower()
    return "crash" in reason or "collision" in reason


def estimate_lag_s(
    t_sp: NDArray[np.float64],
    sp: NDArray[np.float64],
    t_pos: NDArray[np.float64],
    pos: NDArray[np.float64],
    max_lag_s: float = 2.0,
) -> float:
    """Delay (s) of the flown path behind the commanded one: the shift minimising the RMS error."""
    if len(t_sp) < 2 or len(t_pos) < 2:
        return math.nan
    lags = np.arange(0.0, max_lag_s + 1e-9, 0.01)
    errs = []
    for lag in lags:
        shifted = np.stack([np.interp(t_pos - lag, t_sp, sp[:, i]) for i in range(3)], axis=1)
        ok = (t_pos - lag >= t_sp[0]) & (t_pos - lag <= t_sp[-1])
        errs.append(
            np.sqrt(np.mean(np.sum((shifted[ok] - pos[ok]) ** 2, axis=1))) if ok.sum() > 3 else np.inf
        )
    return float(lags[int(np.argmin(errs))])


def fig_tracking(rec: FlightRecord) -> tuple[Figure, float]:
    """Commanded setpoint vs flown position per axis over time, the tracking error, and the lag (s)."""
    t0 = t_zero(rec)
    fig, axes = plt.subplots(4, 1, figsize=(11, 8), sharex=True, constrained_layout=True)
    lag = estimate_lag_s(rec.setpoint_t_s, rec.setpoint_pos_world_m, rec.odom_t_s, rec.odom_pos_world_m)
    for i, name in enumerate(("x (m)", "y (m)", "z (m)")):
        ax = axes[i]
        if len(rec.setpoint_t_s):
            ax.plot(rec.setpoint_t_s - t0, rec.setpoint_pos_world_m[:, i], color="#f28e2b", label="commanded")
        if len(rec.odom_t_s):
            ax.plot(rec.odom_t_s - t0, rec.odom_pos_world_m[:, i], color="#1f77b4", label="flown")
        if rec.steps:
            ax.plot(
                rec.step_t_s - t0,
                rec.step_array("moving_setpoint_world_m")[:, i],
                ".",
                color="#9467bd",
                label="moving setpoint",
            )
        ax.set_ylabel(name)
    legend(axes[0], loc="upper left", fontsize=8, ncol=3)
    ax = axes[3]
    if len(rec.setpoint_t_s) > 1 and len(rec.odom_t_s) > 1:
        sp_at = np.stack(
            [np.interp(rec.odom_t_s, rec.setpoint_t_s, rec.setpoint_pos_world_m[:, i]) for i in range(3)], 1
        )
        err = np.linalg.norm(sp_at - rec.odom_pos_world_m, axis=1)
        ax.plot(rec.odom_t_s - t0, err, color="#d62728", label="|commanded - flown| (m)")
    if rec.steps:
        ax.plot(
            rec.step_t_s - t0, rec.step_array("deviation_m"), color="#8c564b", label="deviation from path (m)"
        )
    ax.set_ylabel("error (m)")
    ax.set_xlabel("time since first decision (s)")
    legend(ax, loc="upper left", fontsize=8, ncol=2)
    axes[0].set_title(f"Setpoint tracking — flown path lags the commanded one by ≈ {lag:.2f} s")
    return fig, lag


def fig_overlay(records: Sequence[FlightRecord]) -> Figure:
    """Top view of several flights over the first record's world."""
    fig, ax = plt.subplots(figsize=(11, 4.5), constrained_layout=True)
    world = world_of(records[0]) if records else None
    _draw_obstacles(ax, world, "top")
    wps = _path_of(records[0], world) if records else None
    if wps is not None:
        ax.plot(wps[:, 0], wps[:, 1], "--", color="#555", label="rough path")
    for rec in records:
        if len(rec.odom_t_s):
            p = rec.odom_pos_world_m
            (line,) = ax.plot(p[:, 0], p[:, 1], lw=1.6, label=rec.name)
            ax.plot(p[-1, 0], p[-1, 1], "X" if _crashed(rec) else "s", color=line.get_color(), ms=8)
    ax.set_xlabel("x (m, forward)")
    ax.set_ylabel("y (m, left)")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_title("All flights, top view (X = crash)")
    legend(ax, fontsize=8, loc="upper left", ncol=3)
    return fig
