"""A privileged teacher: the best primitive in a visited state, planned against the TRUE world.

The DQN sees one depth image and the setpoint; the simulator knows every obstacle. This teacher
uses that (Chen et al., *Learning by cheating*; Loquercio et al. 2021):

1. **A cost-to-go field per world** (:func:`cost_field`): Dijkstra over a voxel grid
   (``grid_m``) of the free space within ``max_deviation_m`` of the path, 26 neighbours, from the
   goal ball outwards. A cell whose clearance (centre to the nearest solid) is under ``comfort_m``
   costs more to cross (``comfort_weight``), so the cheapest route keeps to the middle of a gap;
   cells closer than the quad's radius plus ``margin_m`` to a solid are walls. The field is the
   geometry's alone: the same at every primitive scale.
2. **A lookahead over the primitive lattice** (:meth:`Teacher.action_costs`): from each env's
   exact state (position, velocity, the commanded end point and velocity the next primitive joins,
   the heading frame of the next step) every primitive is flown with the env's own dynamics
   (:func:`quadnav_onboard.step.primitive_targets`, :func:`sim_harness.quad.track`). A
   primitive's cost is the field at its end, plus ``setpoint_weight`` times its distance to the
   moving setpoint, plus ``crash_cost`` if its trail passes closer than the quad's radius plus
   ``margin_m`` to a solid; with ``lookahead`` 2 every primitive after it is flown too, and
   ``crash_cost`` is added again if none of them clears the margin (a dead end). (Scoring a
   primitive by its best continuation's field instead made the first choices near-ties: a
   network imitating them agreed with the teacher on 40 % of its own training states.)

The labels are the costs' arg-min (:meth:`Teacher.labels`) and a soft target over all primitives
(:func:`soft_targets`), which keeps the order of the runners-up: the safety filter falls back on it
when it vetoes the first choice.
"""

from __future__ import annotations

import dataclasses
import heapq
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numba
import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.step import primitive_targets, step_fractions, step_inputs
from sim_harness.collision import clearance_m
from sim_harness.quad import QuadState, track
from sim_harness.rl.imitation import Labels
from sim_harness.world import World

if TYPE_CHECKING:
    from sim_harness.rl.config import TrainConfig

__all__ = [
    "CostField", "Teacher", "TeacherConfig", "TeacherPilot", "cost_field", "released_by",
    "soft_targets", "teacher_config", "vetoed_as_crashes",
]

UNREACHABLE = 1.0e4
"""Field value (m) of cells from which the goal cannot be reached (walls included)."""


@dataclass(frozen=True)
class TeacherConfig:
    """How the teacher plans (every length in metres)."""

    grid_m: float = 0.25
    """Voxel size of the cost-to-go field."""
    comfort_m: float = 0.8
    """Clearance (centre to surface) below which crossing a cell costs more."""
    comfort_weight: float = 4.0
    """Extra cost per metre crossed at the quad's radius (falls linearly to 0 at ``comfort_m``)."""
    margin_m: float = 0.15
    """Clearance beyond the quad's radius a primitive's trail must keep, or it counts as a crash."""
    crash_cost: float = 100.0
    """Cost (m-equivalent) of a step that crashes (in the margin's sense)."""
    lookahead: int = 2
    """Primitives flown: 1, or 2 (the second only to find dead ends)."""
    setpoint_weight: float = 0.1
    """Cost per metre between the first primitive's end and the moving setpoint then (the
    paper's reward tracks it): it breaks the field's near-ties towards the setpoint."""
    max_deviation_m: float = 3.5
    """Cells farther from the path are walls (the episode ends at 5 m; a route along that edge,
    round the outer end of a slalom's panel, is one the primitives' 1 m lattice rarely fits)."""
    goal_radius_m: float = 0.9
    """Cells this close to the goal are the field's zero."""
    respect_filter: bool = False
    """Price the primitives the env's depth filter vetoes (it sees only what the vehicle saw) as
    crashes, where it allows any: the teacher then chooses among what the flown product allows."""
    release_m: float = 0.0
    """With ``respect_filter``: in a state where the filter's vetoes raise the teacher's best cost
    by more than this, the filter boxes it in where the true world has a way on, and the teacher
    chooses there among every primitive (those labels carry no verdicts for the hinge). A hold in
    place costs about one primitive length of progress. 0: never."""

    def __post_init__(self) -> None:
        for name in ("grid_m", "comfort_m", "margin_m", "max_deviation_m", "goal_radius_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"TeacherConfig.{name}: bad value {v!r}: must be finite and > 0")
        for name in ("comfort_weight", "setpoint_weight"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"TeacherConfig.{name}: bad value {v!r}: must be finite and >= 0")
        if not (math.isfinite(self.crash_cost) and self.crash_cost > 0):
            raise ValueError(f"TeacherConfig.crash_cost: bad value {self.crash_cost!r}: must be > 0")
        if self.lookahead not in (1, 2):
            raise ValueError(f"TeacherConfig.lookahead: bad value {self.lookahead!r}: 1 or 2")
        if not (math.isfinite(self.release_m) and self.release_m >= 0):
            raise ValueError(
                f"TeacherConfig.release_m: bad value {self.release_m!r}: must be finite and >= 0"
            )


@numba.njit(cache=True)
def _dijkstra(cost: NDArray, source: NDArray, res: float) -> NDArray:  # pragma: no cover (numba)
    """Least cost from every cell to a source cell; ``cost`` (nx, ny, nz) per metre crossed
    (inf = wall); an edge costs its length times the mean of its two cells' costs."""
    nx, ny, nz = cost.shape
    dist = np.full(cost.shape, np.inf)
    heap = [(0.0, -1, -1, -1)]  # a typed first entry (numba), skipped below
    for i in range(nx):
        for j in range(ny):
            for k in range(nz):
                if source[i, j, k] and np.isfinite(cost[i, j, k]):
                    dist[i, j, k] = 0.0
                    heap.append((0.0, i, j, k))
    heapq.heapify(heap)
    while heap:
        d, i, j, k = heapq.heappop(heap)
        if i < 0 or d > dist[i, j, k]:
            continue
        c0 = cost[i, j, k]
        for di in range(-1, 2):
            ii = i + di
            if ii < 0 or ii >= nx:
                continue
            for dj in range(-1, 2):
                jj = j + dj
                if jj < 0 or jj >= ny:
                    continue
                for dk in range(-1, 2):
                    kk = k + dk
                    if kk < 0 or kk >= nz or (di == 0 and dj == 0 and dk == 0):
                        continue
                    c1 = cost[ii, jj, kk]
                    if not np.isfinite(c1):
                        continue
                    nd = d + res * math.sqrt(di * di + dj * dj + dk * dk) * 0.5 * (c0 + c1)
                    if nd < dist[ii, jj, kk]:
                        dist[ii, jj, kk] = nd
                        heapq.heappush(heap, (nd, ii, jj, kk))
    return dist


@dataclass(frozen=True)
class CostField:
    """Cost-to-go (m-equivalent) on a voxel grid; :meth:`__call__` interpolates it."""

    origin_m: NDArray[np.float64]
    grid_m: float
    values: NDArray[np.float64]
    """(nx, ny, nz); :data:`UNREACHABLE` where the goal cannot be reached."""

    def __call__(self, pos_m: NDArray[np.float64]) -> NDArray[np.float64]:
        """Trilinear interpolation at positions (..., 3) over the reachable corners of each
        position's cell, their weights renormalised; :data:`UNREACHABLE` outside the grid or where
        no corner is reachable.

        A wall corner does not count: blended in, its :data:`UNREACHABLE` would make every point
        within a cell of a wall cost thousands of metres, a margin one cell wider than
        ``margin_m`` that closes gaps the primitives fit through (the lookahead's crash check,
        not the field, says whether a primitive's trail keeps the margin)."""
        p = (np.asarray(pos_m, dtype=np.float64) - self.origin_m) / self.grid_m
        shape = np.array(self.values.shape)
        inside = np.all((p >= 0) & (p <= shape - 1), axis=-1)
        p = np.clip(p, 0, shape - 1 - 1e-9)
        i0 = np.floor(p).astype(np.int64)
        f = p - i0
        total = np.zeros(p.shape[:-1])
        weight = np.zeros(p.shape[:-1])
        for dx in (0, 1):
            wx = f[..., 0] if dx else 1 - f[..., 0]
            for dy in (0, 1):
                wy = f[..., 1] if dy else 1 - f[..., 1]
                for dz in (0, 1):
                    wz = f[..., 2] if dz else 1 - f[..., 2]
                    v = self.values[i0[..., 0] + dx, i0[..., 1] + dy, i0[..., 2] + dz]
                    w = np.where(v < UNREACHABLE, wx * wy * wz, 0.0)
                    total += w * v
                    weight += w
        reachable = inside & (weight > 1e-12)
        return np.where(reachable, total / np.maximum(weight, 1e-12), UNREACHABLE)


def teacher_config(cfg: TrainConfig, **overrides: Any) -> TeacherConfig:
    """The teacher a training config asks for: each ``teacher_*`` key of ``cfg`` sets the
    :class:`TeacherConfig` field of the same name without the prefix; ``overrides`` set fields
    the flight decides (a lab's finer grid, its deviation limit and goal radius)."""
    keys = {
        f.name.removeprefix("teacher_"): getattr(cfg, f.name)
        for f in dataclasses.fields(cfg) if f.name.startswith("teacher_")
    }
    return TeacherConfig(**{**keys, **overrides})


def cost_field(world: World, radius_m: float, config: TeacherConfig = TeacherConfig()) -> CostField:
    """The cost-to-go field of ``world`` for a quad of ``radius_m`` (see the module docstring)."""
    g = config.grid_m
    pts = world.path.waypoints_m
    pad = config.max_deviation_m + 1.0
    lo = pts.min(axis=0) - pad
    hi = pts.max(axis=0) + pad
    if world.floor_z_m is not None:
        lo[2] = max(lo[2], world.floor_z_m)
    if world.ceiling_z_m is not None:
        hi[2] = min(hi[2], world.ceiling_z_m)
    axes = [np.arange(lo[d], hi[d] + 1e-9, g) for d in range(3)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
    shape = grid.shape[:3]
    flat = grid.reshape(-1, 3)
    clear = clearance_m(world, flat).reshape(shape)
    deviation = world.path.deviation_m(flat).reshape(shape)
    wall = radius_m + config.margin_m  # as the lookahead counts a crash
    span = max(config.comfort_m - wall, 1e-6)
    tight = np.clip((config.comfort_m - clear) / span, 0.0, 1.0)
    cost = 1.0 + config.comfort_weight * tight
    cost[(clear < wall) | (deviation > config.max_deviation_m)] = np.inf
    source = np.linalg.norm(grid - world.path.goal_m, axis=-1) <= config.goal_radius_m
    dist = _dijkstra(cost, source, g)
    return CostField(lo, g, np.where(np.isfinite(dist), dist, UNREACHABLE))


def soft_targets(costs: NDArray[np.float64], temperature_m: float) -> NDArray[np.float32]:
    """A distribution over primitives (N, A) from the teacher's costs: softmax of ``-cost / T``."""
    z = -(costs - costs.min(axis=1, keepdims=True)) / temperature_m
    p = np.exp(z)
    return (p / p.sum(axis=1, keepdims=True)).astype(np.float32)


def vetoed_as_crashes(costs: NDArray[np.float64], allowed: NDArray[np.bool_], crash_cost: float
                      ) -> NDArray[np.float64]:
    """``costs`` (N, A) plus ``crash_cost`` on each primitive the filter does not ``allow`` (N, A);
    a row the filter vetoes entirely is left as it is (the product then flies the arg-max of all,
    :func:`~quadnav_onboard.policy.masked_argmax`)."""
    allowed = np.asarray(allowed, dtype=bool)
    if allowed.shape != costs.shape:
        raise ValueError(f"costs {costs.shape} and the filter's verdicts {allowed.shape} differ in shape")
    vetoed = ~allowed & allowed.any(axis=1, keepdims=True)
    return costs + crash_cost * vetoed


def released_by(costs: NDArray[np.float64], chosen: NDArray[np.float64], release_m: float
                ) -> NDArray[np.bool_]:
    """The rows (N,) where pricing the filter's vetoes (``chosen``, from ``costs``, both (N, A))
    raises the best cost by more than ``release_m``: the filter boxes the teacher in there."""
    return chosen.min(axis=1) - costs.min(axis=1) > release_m


class Teacher:
    """Labels the states of a :class:`~sim_harness.env.VecQuadNavEnv` with the TRUE geometry.

    ``fields`` are built on first use per world (keyed by the world's object id: the env's worlds
    list is fixed) and shared between envs over the same worlds at any primitive scale.
    """

    loss = "cross_entropy"
    """How the student fits the labels (:func:`sim_harness.rl.imitation.fit`)."""

    def __init__(self, config: TeacherConfig = TeacherConfig()) -> None:
        self.config = config
        self._fields: dict[tuple[int, float], CostField] = {}

    def label(self, env, depth: NDArray, rel: NDArray, temperature_m: float) -> Labels:
        """Soft targets (N, A), the teacher's actions (N,) and the states where it left the
        filter's verdicts aside (``release_m``), for every env of ``env``."""
        costs, released = self._choice(env, np.arange(env.n_envs))
        return Labels(soft_targets(costs, temperature_m), np.argmin(costs, axis=1), released)

    def field(self, world: World, radius_m: float) -> CostField:
        key = (id(world.geometry), float(radius_m))
        if key not in self._fields:
            self._fields[key] = cost_field(world, radius_m, self.config)
        return self._fields[key]

    def action_costs(self, env, ids: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """Cost of every primitive (len(ids), A) at the next decision of the envs ``ids`` (all
        running ones if None). One batched rollout for all of them, whatever their worlds."""
        ids = np.flatnonzero(~env.done) if ids is None else np.asarray(ids, dtype=np.int64)
        cfg, a_n = self.config, env.prims.n_actions
        radius = env.config.quad.radius_m
        limit = radius + cfg.margin_m
        m = ids.size
        wid = env.world_idx[ids]
        p1, v1, c1, cv1, clear1 = self._rollout(
            env, wid, env.pos_m[ids], env.vel_m_s[ids], env.cmd_pos_m[ids], env.cmd_vel_m_s[ids],
            env.steps[ids],
        )
        wid1 = np.repeat(wid, a_n)
        setpoint = np.zeros((m, 3))
        for w, sel in _groups(wid):
            setpoint[sel] = env.worlds[w].path.setpoint_at((env.steps[ids[sel]] + 1) * env.prims.duration_s)
        tracking = np.linalg.norm(p1.reshape(m, a_n, 3) - setpoint[:, None], axis=-1).reshape(-1)
        to_go = self._field(env, wid1, p1, radius)
        crash = cfg.crash_cost * (clear1 < limit)
        if cfg.lookahead == 2:  # a dead end: no second primitive clears the margin
            steps1 = np.repeat(env.steps[ids] + 1, a_n)
            _, _, _, _, clear2 = self._rollout(env, wid1, p1, v1, c1, cv1, steps1, every=4)
            crash = crash + cfg.crash_cost * ~(clear2.reshape(m * a_n, a_n) >= limit).any(axis=1)
        return (to_go + crash + cfg.setpoint_weight * tracking).reshape(m, a_n)

    def choice_costs(self, env, ids: NDArray[np.int64] | None = None) -> NDArray[np.float64]:
        """:meth:`action_costs`, with the filter's vetoes priced as crashes when the teacher
        respects the filter (``TeacherConfig.respect_filter``), except where they cost it more
        than ``TeacherConfig.release_m``."""
        return self._choice(env, ids)[0]

    def _choice(self, env, ids: NDArray[np.int64] | None
                ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
        """(:meth:`choice_costs`, the rows where the teacher left the filter's vetoes aside)."""
        ids = np.flatnonzero(~env.done) if ids is None else np.asarray(ids, dtype=np.int64)
        costs = self.action_costs(env, ids)
        released = np.zeros(len(ids), dtype=bool)
        if not self.config.respect_filter:
            return costs, released
        if env.memory is None:
            raise ValueError("the teacher respects the filter only with the env's filter on "
                             "(EnvConfig.shield.enabled)")
        chosen = vetoed_as_crashes(costs, np.asarray(env.allowed)[ids], self.config.crash_cost)
        if self.config.release_m > 0:
            released = released_by(costs, chosen, self.config.release_m)
            chosen[released] = costs[released]
        return chosen, released

    def labels(self, env, ids: NDArray[np.int64] | None = None) -> NDArray[np.int64]:
        """The teacher's primitive (the arg-min of :meth:`choice_costs`) for the envs ``ids``."""
        return np.argmin(self.choice_costs(env, ids), axis=1)

    def _field(self, env, wid: NDArray[np.int64], pos: NDArray, radius_m: float) -> NDArray:
        out = np.empty(pos.shape[0])
        for w, sel in _groups(wid):
            out[sel] = self.field(env.worlds[w], radius_m)(pos[sel])
        return out

    def _rollout(
        self, env, wid: NDArray[np.int64], pos, vel, cmd_pos, cmd_vel, steps, every: int = 1
    ) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray]:
        """Every primitive from each of M states (in the worlds ``wid``): end states (M*A, ...)
        and the trails' least clearance (M*A,), checked at every ``every``-th sample and the end."""
        prims, a_n = env.prims, env.prims.n_actions
        m = pos.shape[0]
        yaw = np.zeros(m)
        for w, sel in _groups(wid):
            yaw[sel] = step_inputs(env.worlds[w].path, steps[sel], prims.duration_s, pos[sel]).yaw_rad
        rep = lambda x: np.repeat(x, a_n, axis=0)  # noqa: E731
        actions = np.tile(np.arange(a_n), m)
        u = step_fractions(prims.duration_s, env.config.quad.dt_s)  # as the env samples it
        targets, target_vel = primitive_targets(prims, actions, rep(cmd_pos), rep(cmd_vel), rep(yaw), u)
        state, trail = track(QuadState(rep(pos), rep(vel)), targets, target_vel, env.config.quad)
        keep = np.unique(np.r_[np.arange(0, trail.shape[0], every), trail.shape[0] - 1])
        pts = trail[keep]  # (k, M*A, 3)
        clear = np.empty(m * a_n)
        for w, sel in _groups(np.repeat(wid, a_n)):
            sub = np.ascontiguousarray(pts[:, sel])
            clear[sel] = clearance_m(env.worlds[w], sub.reshape(-1, 3)).reshape(sub.shape[:2]).min(axis=0)
        return state.pos_m, state.vel_m_s, targets[-1], target_vel[-1], clear


def _groups(wid: NDArray[np.int64]) -> list[tuple[int, NDArray[np.int64]]]:
    return [(int(w), np.flatnonzero(wid == w)) for w in np.unique(wid)]


def teacher_for(worlds: Sequence[World], radius_m: float, config: TeacherConfig) -> Teacher:
    """A teacher with the fields of ``worlds`` built now (so their cost is paid up front)."""
    t = Teacher(config)
    for w in worlds:
        t.field(w, radius_m)
    return t


class TeacherPilot:
    """The teacher flying an eval's flights in place of a network: pass :meth:`act` and
    :meth:`on_world_start` to :func:`sim_harness.rl.evaluate.evaluate` (the teacher reads each
    world's env, not the depth images). Counts the decisions whose primitive the env's filter
    would have vetoed (none when the teacher respects the filter, unless it vetoes all)."""

    def __init__(self, teacher: Teacher) -> None:
        self.teacher = teacher
        self.env = None
        self.decisions = 0
        """Decisions taken with the env's filter on."""
        self.vetoed = 0
        """Of those, decisions whose primitive the filter vetoed while allowing another."""

    def on_world_start(self, _world: World, env) -> None:
        self.env = env

    def act(self, depth: NDArray, rel: NDArray, allowed: NDArray[np.bool_]) -> NDArray[np.int64]:
        env = self.env
        if env is None:
            raise RuntimeError("TeacherPilot.act before on_world_start: pass both to evaluate()")
        actions = np.zeros(env.n_envs, dtype=np.int64)
        running = np.flatnonzero(~env.done)
        if running.size:
            actions[running] = self.teacher.labels(env, running)
            if env.memory is not None:
                ok = np.asarray(allowed)[running]
                chosen = ok[np.arange(running.size), actions[running]]
                self.decisions += running.size
                self.vetoed += int((ok.any(axis=1) & ~chosen).sum())
        return actions
