"""Pictures of worlds: top and side views (path, obstacles, bounds) and, given a pose, what the
camera sees (the full depth frame and the network's 32x32 input).

Pure matplotlib object API on the Agg canvas (no pyplot state, no display needed); the only I/O
is :func:`save_world_png`.
"""

from __future__ import annotations

import math
import textwrap
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Circle, Polygon, Rectangle

from quadnav_onboard.frames import quat_from_yaw
from quadnav_onboard.preprocess import DepthFrameError, preprocess_depth_mm
from sim_harness.render import CameraModel, D435_424x240, render_frame_mm
from sim_harness.world import Box, Obstacle, Sphere, World

__all__ = ["draw_world", "save_world_png"]

_FACE = "#c0504d"
_EDGE = "#7f2a28"


def _box_corners_xy(ob: Box) -> np.ndarray:
    """Footprint corners (world x, y) of a yawed box, shape (4, 2)."""
    hx, hy = ob.size_m[0] / 2, ob.size_m[1] / 2
    c, s = math.cos(math.radians(ob.yaw_deg)), math.sin(math.radians(ob.yaw_deg))
    local = np.array([[-hx, -hy], [hx, -hy], [hx, hy], [-hx, hy]])
    return local @ np.array([[c, s], [-s, c]]) + np.array(ob.center_m[:2])


def _patch(ob: Obstacle, view: str, faded: bool = False):  # -> matplotlib Patch
    """The obstacle's outline seen from above (``view="top"``: x-y) or the side (``"side"``: x-z);
    ``faded``: outline only (for what is beside the path in that view, e.g. corridor walls)."""
    cx, cy, cz = ob.center_m
    style = {"facecolor": _FACE, "edgecolor": _EDGE, "alpha": 0.55, "linewidth": 1.0}
    if faded:
        style = {"facecolor": "none", "edgecolor": _EDGE, "alpha": 0.6, "linewidth": 0.8, "linestyle": "--"}
    second = cy if view == "top" else cz
    if isinstance(ob, Sphere):
        return Circle((cx, second), ob.radius_m, **style)
    if isinstance(ob, Box):
        corners = _box_corners_xy(ob)
        if view == "top":
            return Polygon(corners, closed=True, **style)
        x0, x1 = corners[:, 0].min(), corners[:, 0].max()
        return Rectangle((x0, cz - ob.size_m[2] / 2), x1 - x0, ob.size_m[2], **style)
    r, h = ob.radius_m, ob.height_m
    if view == "top":
        if ob.axis == "z":
            return Circle((cx, cy), r, **style)
        w, d = (h, 2 * r) if ob.axis == "x" else (2 * r, h)
        return Rectangle((cx - w / 2, cy - d / 2), w, d, **style)
    if ob.axis == "y":
        return Circle((cx, cz), r, **style)
    w, d = (h, 2 * r) if ob.axis == "x" else (2 * r, h)
    return Rectangle((cx - w / 2, cz - d / 2), w, d, **style)


def _aabb(ob: Obstacle) -> tuple[np.ndarray, np.ndarray]:
    """World-axis-aligned bounds (m) of an obstacle: (min (3,), max (3,))."""
    c = np.array(ob.center_m)
    if isinstance(ob, Sphere):
        half = np.full(3, ob.radius_m)
    elif isinstance(ob, Box):
        xy = _box_corners_xy(ob)
        return (np.array([*xy.min(axis=0), c[2] - ob.size_m[2] / 2]),
                np.array([*xy.max(axis=0), c[2] + ob.size_m[2] / 2]))
    else:
        half = np.full(3, ob.radius_m)
        half["xyz".index(ob.axis)] = ob.height_m / 2
    return c - half, c + half


def _extent(world: World) -> tuple[tuple[float, float], tuple[float, float], tuple[float, float]]:
    """Plot ranges (m) in x, y and z that hold the path, the obstacles near it and the bounds."""
    wps = world.path.waypoints_m
    xs = [wps[:, 0].min() - 3, wps[:, 0].max() + 3]
    ys = [wps[:, 1].min() - 4, wps[:, 1].max() + 4]
    for ob in world.obstacles:
        lo, hi = _aabb(ob)
        xs += [lo[0], hi[0]]
        ys += [lo[1], hi[1]]
    y_lo = max(min(ys), wps[:, 1].min() - 10)
    y_hi = min(max(ys), wps[:, 1].max() + 10)
    z_lo = world.floor_z_m if world.floor_z_m is not None else wps[:, 2].min() - 3
    z_hi = world.ceiling_z_m if world.ceiling_z_m is not None else wps[:, 2].max() + 3
    return (min(xs), max(xs)), (y_lo, y_hi), (z_lo - 0.5, z_hi + 0.5)


def _draw_view(ax: Axes, world: World, view: str, pose_m: np.ndarray | None, yaw_rad: float,
               camera: CameraModel) -> None:
    wps = world.path.waypoints_m
    k = 1 if view == "top" else 2
    (x_lo, x_hi), y_range, z_range = _extent(world)
    hidden_axis = 2 if view == "top" else 1  # the axis this view looks along
    path_lo, path_hi = wps[:, hidden_axis].min(), wps[:, hidden_axis].max()
    for ob in world.obstacles:
        lo, hi = _aabb(ob)
        ax.add_patch(_patch(ob, view, faded=hi[hidden_axis] < path_lo or lo[hidden_axis] > path_hi))
    ax.plot(wps[:, 0], wps[:, k], "--", color="#1f77b4", lw=1.2, label="rough path")
    ax.plot(*wps[0, [0, k]], "o", color="#2ca02c", ms=7, label="start")
    ax.plot(*wps[-1, [0, k]], "*", color="#d4a017", ms=12, label="goal")
    if view == "side":
        for z, name in ((world.floor_z_m, "floor"), (world.ceiling_z_m, "ceiling")):
            if z is not None:
                ax.axhline(z, color="#555555", lw=2.0)
                ax.text(x_lo + 0.5, z, name, va="bottom" if name == "floor" else "top", fontsize=8)
        ax.set_ylim(*z_range)
        ax.set_ylabel("z up (m)")
    else:
        ax.set_ylim(*y_range)
        ax.set_ylabel("y left (m)")
    if pose_m is not None:
        ax.plot(pose_m[0], pose_m[k], "o", color="black", ms=6, label="pose")
        if view == "top":  # the horizontal field of view, out to max range
            half = math.radians(camera.hfov_deg) / 2
            rng_m = camera.max_range_m
            rays = [np.array([math.cos(yaw_rad + a), math.sin(yaw_rad + a)]) for a in (-half, half)]
            tri = [pose_m[:2]] + [pose_m[:2] + rng_m * r for r in rays]
            ax.add_patch(Polygon(tri, closed=True, facecolor="#888888", alpha=0.15, edgecolor="#444444"))
    ax.set_xlim(x_lo, x_hi)
    ax.set_aspect("equal")
    ax.set_xlabel("x forward (m)")
    ax.grid(True, lw=0.3, alpha=0.5)


def draw_world(world: World, pose_m: np.ndarray | None = None, yaw_rad: float = 0.0,
               camera: CameraModel = D435_424x240) -> Figure:
    """A figure of ``world``: top and side views; with ``pose_m`` (world, m, (3,)) and ``yaw_rad``
    also the rendered depth frame (``camera``) and the 32x32 network input at that pose."""
    with_pose = pose_m is not None
    (x_lo, x_hi), (y_lo, y_hi), (z_lo, z_hi) = _extent(world)
    width_in = 14.0
    views_in = (width_in - 1.5) * (y_hi - y_lo + z_hi - z_lo) / (x_hi - x_lo) + 2.0
    fig = Figure(figsize=(width_in, views_in + (4.5 if with_pose else 0.0) + 1.0), layout="constrained")
    FigureCanvasAgg(fig)
    ratios = [y_hi - y_lo, z_hi - z_lo] + ([0.6 * (x_hi - x_lo) * 4.5 / width_in] if with_pose else [])
    grid = fig.add_gridspec(len(ratios), 2, height_ratios=ratios)
    pose = None if pose_m is None else np.asarray(pose_m, dtype=np.float64)
    top = fig.add_subplot(grid[0, :])
    side = fig.add_subplot(grid[1, :])
    _draw_view(top, world, "top", pose, yaw_rad, camera)
    _draw_view(side, world, "side", pose, yaw_rad, camera)
    top.set_title("top view")
    side.set_title("side view")
    top.legend(loc="upper right", fontsize=8, ncols=4)
    title = f"{world.name}: {len(world.obstacles)} obstacles, path {world.path.length_m:.0f} m"
    text = "\n".join([title, *textwrap.wrap(world.description, 150)])
    fig.suptitle(text, fontsize=10)
    if pose is not None:
        frame = render_frame_mm(world, pose, quat_from_yaw(yaw_rad), camera)
        depth = np.where(frame > 0, frame / 1000.0, np.nan)
        ax = fig.add_subplot(grid[2, 0])
        img = ax.imshow(depth, cmap="viridis_r", vmin=0.0, vmax=camera.max_range_m, interpolation="nearest")
        ax.set_facecolor("black")
        fig.colorbar(img, ax=ax, label="z-depth (m); black = no return")
        where = f"({pose[0]:.1f}, {pose[1]:.1f}, {pose[2]:.1f}) m, yaw {math.degrees(yaw_rad):.0f} deg"
        ax.set_title(f"depth {camera.width}x{camera.height} at {where}")
        ax = fig.add_subplot(grid[2, 1])
        try:
            net = preprocess_depth_mm(frame)
            img = ax.imshow(net, cmap="gray", vmin=0.0, vmax=1.0, interpolation="nearest")
            fig.colorbar(img, ax=ax, label="network input (depth / max range)")
            ax.set_title("network input 32x32")
        except DepthFrameError as exc:
            ax.text(0.5, 0.5, f"no network input:\n{exc}", ha="center", va="center", wrap=True)
            ax.set_axis_off()
    return fig


def save_world_png(world: World, path: str | Path, pose_m: np.ndarray | None = None, yaw_rad: float = 0.0,
                   camera: CameraModel = D435_424x240, dpi: int = 110) -> Path:
    """Draw ``world`` (see :func:`draw_world`) and write it as a PNG; returns the path written."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    draw_world(world, pose_m, yaw_rad, camera).savefig(out, dpi=dpi)
    return out
