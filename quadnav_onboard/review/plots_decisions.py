"""The report's figures about what the flight saw and chose, and when things happened.

Q-values and actions per decision, the network input at each decision, raw depth, the
mode/armed/event timeline, latency histograms. Times are seconds since the first decision.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure

from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.record.reader import FlightRecord
from quadnav_onboard.review.plots import legend, t_zero

__all__ = ["action_label", "fig_decisions", "fig_depth", "fig_inputs", "fig_latency", "fig_modes"]

_DEPTH_CMAP = matplotlib.colormaps["turbo"].with_extremes(bad="#c8c8c8")


def action_label(a: int) -> str:
    if 0 <= a < len(DEFAULT_DIRECTIONS):
        f, lat, v = DEFAULT_DIRECTIONS[a]
        return (
            f"{a:2d} " + ("F" if f else "·") + {-1: "R", 0: "·", 1: "L"}[lat] + {-1: "D", 0: "·", 1: "U"}[v]
        )
    return str(a)


def fig_decisions(rec: FlightRecord) -> Figure:
    """Q-values of all actions per step (heat map, chosen action ringed), reward, progress."""
    fig, axes = plt.subplots(
        3, 1, figsize=(11, 9), sharex=True, constrained_layout=True, gridspec_kw={"height_ratios": [3, 1, 1]}
    )
    if not rec.steps:
        axes[0].text(0.5, 0.5, "no decisions recorded", ha="center", transform=axes[0].transAxes)
        return fig
    steps = rec.step_array("step")
    q = rec.step_array("q_values")
    act = rec.step_array("action").astype(int)
    ax = axes[0]
    im = ax.imshow(
        q.T,
        aspect="auto",
        origin="lower",
        cmap="viridis",
        interpolation="nearest",
        extent=(steps[0] - 0.5, steps[-1] + 0.5, -0.5, q.shape[1] - 0.5),
    )
    ax.scatter(
        steps, act, s=40, facecolors="none", edgecolors="#ff3030", linewidths=1.6, label="chosen action"
    )
    veto = [(s["step"], a) for s in rec.steps for a, ok in enumerate(s.get("shield_allowed") or []) if not ok]
    if veto:
        vs, va = zip(*veto, strict=True)
        ax.scatter(vs, va, s=14, marker="x", color="white", linewidths=0.9, label="vetoed by the filter")
    ax.set_yticks(range(q.shape[1]))
    ax.set_yticklabels([action_label(a) for a in range(q.shape[1])], fontsize=7, family="monospace")
    ax.set_ylabel("action (F fwd, L/R left/right, U/D up/down)")
    title = "Q-values per decision (colour) and the chosen primitive (red ring)"
    ax.set_title(title + (", primitives the depth safety filter vetoed (x)" if veto else ""))
    legend(ax, loc="upper right", fontsize=8)
    fig.colorbar(im, ax=ax, label="Q-value", pad=0.01)
    axes[1].bar(steps, rec.step_array("reward"), color="#2ca02c")
    axes[1].set_ylabel("reward")
    axes[2].plot(steps, rec.step_array("progress_m"), color="#1f77b4", label="progress along path (m)")
    axes[2].plot(
        steps,
        np.linalg.norm(rec.step_array("rel_pos_body_m"), axis=1),
        color="#9467bd",
        label="distance to moving setpoint (m)",
    )
    axes[2].set_ylabel("m")
    axes[2].set_xlabel("decision step")
    legend(axes[2], loc="upper left", fontsize=8)
    return fig


def fig_inputs(rec: FlightRecord, max_tiles: int = 120) -> Figure:
    """What the network saw: the 32×32 depth input at each decision, labelled with the action chosen."""
    inputs = rec.network_inputs
    if len(inputs) > max_tiles:
        idx = np.linspace(0, len(inputs) - 1, max_tiles).astype(int)
        inputs = [inputs[i] for i in idx]
    actions = {int(s["step"]): int(s["action"]) for s in rec.steps}
    n = max(1, len(inputs))
    cols = min(12, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(11, 1.05 * rows + 0.6), squeeze=False, constrained_layout=True
    )
    for ax in axes.flat:
        ax.axis("off")
    for ax, (_, step, img) in zip(axes.flat, inputs, strict=False):
        ax.imshow(img, cmap="magma", vmin=0.0, vmax=1.0, interpolation="nearest")
        a = actions.get(step)
        ax.set_title(
            f"{step}: {action_label(a).strip() if a is not None else '?'}", fontsize=7, family="monospace"
        )
    fig.suptitle(
        "Network input at each decision (near = dark, far/no return = bright; title = step: action)",
        fontsize=10,
    )
    return fig


def fig_depth(rec: FlightRecord, max_frames: int = 8) -> Figure:
    """Raw depth frames (decimated), evenly spaced over the flight, in metres."""
    frames = rec.depth
    if len(frames) > max_frames:
        idx = np.linspace(0, len(frames) - 1, max_frames).astype(int)
        frames = [frames[i] for i in idx]
    n = max(1, len(frames))
    cols = min(4, n)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(
        rows, cols, figsize=(11, 1.75 * rows + 0.6), squeeze=False, constrained_layout=True
    )
    t0 = t_zero(rec)
    im = None
    for ax in axes.flat:
        ax.axis("off")
    for ax, (t, img) in zip(axes.flat, frames, strict=False):
        m = np.where(img == 0, np.nan, img.astype(np.float32) / 1000.0)
        im = ax.imshow(m, cmap=_DEPTH_CMAP, vmin=0.0, vmax=10.0)
        ax.set_title(f"t = {t - t0:.1f} s", fontsize=8)
    if im is not None:
        fig.colorbar(im, ax=axes, label="depth (m; grey = no return)", shrink=0.8)
    fig.suptitle("Raw depth (decimated)", fontsize=10)
    return fig


_MODE_COLORS = {
    "OFFBOARD": "#2ca02c",
    "HOLD": "#ff7f0e",
    "LAND": "#d62728",
    "TAKEOFF": "#17becf",
    "MANUAL": "#7f7f7f",
    "RTL": "#9467bd",
    "POSCTL": "#bcbd22",
}
_LEVEL_COLORS = {0: "#7f7f7f", 1: "#7f7f7f", 2: "#1f77b4", 3: "#ff7f0e", 4: "#d62728", 5: "#8b0000"}


def fig_modes(rec: FlightRecord) -> Figure:
    """Flight mode and armed state over time, with supervisor events (failsafes) marked."""
    t0 = t_zero(rec)
    fig, ax = plt.subplots(figsize=(11, 3.2), constrained_layout=True)
    t_end = max(
        [t0]
        + [float(v["t_mono_s"]) for v in rec.vehicle]
        + ([float(rec.stop["t_mono_s"])] if rec.stop else [])
        + [float(e["t_mono_s"]) for e in rec.events]
    )
    segs: list[tuple[float, float, str, bool]] = []
    for i, v in enumerate(rec.vehicle):
        t_next = float(rec.vehicle[i + 1]["t_mono_s"]) if i + 1 < len(rec.vehicle) else t_end
        segs.append(
            (float(v["t_mono_s"]) - t0, t_next - float(v["t_mono_s"]), str(v["mode"]), bool(v["armed"]))
        )
    seen: set[str] = set()
    for start, width, mode, armed in segs:
        color = _MODE_COLORS.get(mode, "#aaaaaa")
        ax.broken_barh(
            [(start, max(width, 0.05))], (1.0, 0.8), color=color, label=mode if mode not in seen else None
        )
        ax.broken_barh([(start, max(width, 0.05))], (0.0, 0.8), color="#444" if armed else "#ddd")
        seen.add(mode)
    for e in rec.events:
        te = float(e["t_mono_s"]) - t0
        c = _LEVEL_COLORS.get(int(e.get("level", 2)), "#1f77b4")
        ax.axvline(te, color=c, lw=1.5, ls="--")
        ax.text(te, 2.05, str(e.get("kind", "")), rotation=30, fontsize=8, color=c, va="bottom")
    if rec.stop:
        ts = float(rec.stop["t_mono_s"]) - t0
        ax.axvline(ts, color="k", lw=2)
        ax.text(ts, -0.45, f"stop: {rec.stop.get('stop_reason')}", fontsize=9, ha="right")
    ax.set_yticks([0.4, 1.4])
    ax.set_yticklabels(["armed", "mode"])
    ax.set_ylim(-0.6, 3.0)
    ax.set_xlabel("time since first decision (s)")
    ax.set_title("Vehicle mode / armed (dark = armed) and events")
    if seen:
        legend(ax, loc="upper right", fontsize=8, ncol=len(seen))
    return fig


def fig_latency(rec: FlightRecord) -> Figure:
    """Histograms: decision latency (depth capture to setpoint), odometry and setpoint intervals."""
    series = [
        ("decision latency (ms)", rec.step_array("latency_ms") if rec.steps else np.zeros(0), "#1f77b4"),
        ("odometry interval (ms)", np.diff(rec.odom_t_s) * 1e3, "#2ca02c"),
        ("setpoint interval (ms)", np.diff(rec.setpoint_t_s) * 1e3, "#f28e2b"),
    ]
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2), constrained_layout=True)
    for ax, (label, vals, color) in zip(axes, series, strict=True):
        vals = vals[np.isfinite(vals)]
        if len(vals):
            lo, hi = float(vals.min()), float(vals.max())
            if hi - lo < 1.0:  # near-constant (e.g. a fixed-rate sim): widen so ticks stay readable
                lo, hi = lo - 1.0, hi + 1.0
            ax.hist(vals, bins=30, range=(lo, hi), color=color)
            ax.ticklabel_format(axis="x", useOffset=False, style="plain")
            p50, p99 = np.percentile(vals, [50, 99])
            ax.set_title(f"p50 {p50:.1f} · p99 {p99:.1f} · max {vals.max():.1f}", fontsize=9)
        else:
            ax.set_title("no data", fontsize=9)
        ax.set_xlabel(label)
    axes[0].set_ylabel("count")
    return fig
