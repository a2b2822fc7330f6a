"""The RL environment: the paper's navigation task, vectorised in numpy, plus a Gymnasium wrapper.

Step semantics are the flight semantics. At step k (0-based) the moving setpoint is
``path.setpoint_at(k * duration_s)`` and the position input is
``path.relative_state(setpoint, pos, yaw)`` with ``yaw`` the path heading at the quad's progress.
The chosen primitive starts at the previous *commanded* end point with ``v0`` = the previous
commanded end velocity (C1 joins), in the heading frame; the kinematic quad
(:func:`sim_harness.quad.track`) follows it sampled at ``QuadParams.dt_s``; collisions are swept
along the executed trail (:func:`sim_harness.collision.sweep_collides`); the reward is the paper's
(:func:`quadnav_onboard.reward.reward`). An episode ends on, in this order: collision ("crash"),
deviation past ``max_deviation_m`` ("deviation"), goal reached ("goal": within ``goal_radius_m`` of
the goal or progress >= path length), step limit ("timeout", a truncation).

:class:`VecQuadNavEnv` steps N environments at once (numpy, auto-reset optional) and is what
training and evaluation use; :class:`QuadNavEnv` is the single-env Gymnasium view of it and
:class:`QuadNavVectorEnv` the Gymnasium 1.x ``VectorEnv`` one (its autoreset modes). Importing this
module registers ``quadnav/QuadNav-v0``: ``gymnasium.make("quadnav/QuadNav-v0", world=1)`` and
``gymnasium.make_vec("quadnav/QuadNav-v0", num_envs=16, world=[1, 2, 3])`` (or, without importing it
first, ``gymnasium.make("sim_harness.env:quadnav/QuadNav-v0", ...)``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any

import gymnasium as gym
import numpy as np
import pydantic
from numpy.typing import NDArray

from quadnav_onboard.config import PrimitiveConfig
from quadnav_onboard.preprocess import OUT_SIZE, DepthInputs, PreprocessConfig
from quadnav_onboard.reward import RewardParams
from quadnav_onboard.shield import PointMemory, ShieldConfig, shield_at_scale, shield_verdict
from quadnav_onboard.step import (
    OUTCOMES,
    EpisodeLimits,
    Outcome,
    StepInputs,
    StepRecord,
    finish_step,
    primitive_targets,
    push_history,
    step_fractions,
    step_inputs,
)
from sim_harness.collision import clearance_m, collides, sweep_collides
from sim_harness.quad import QuadParams, QuadState, track
from sim_harness.render import render_inputs
from sim_harness.world import World, load_world, paper_world_path

__all__ = [
    "ENV_ID",
    "OUTCOMES",
    "REFERENCE_SCALE_M",
    "EnvConfig",
    "QuadNavEnv",
    "QuadNavVectorEnv",
    "VecQuadNavEnv",
    "at_primitive_scale",
    "make_env",
    "make_vector_env",
    "observation_space",
    "rel_pos_bound_m",
]



@dataclass(frozen=True)
class EnvConfig:
    """The navigation task (defaults: the paper's simulation settings)."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    max_steps: Annotated[int, pydantic.Field(ge=1)] = 120
    """Step limit per episode (the paper tests with 120 one-second steps on a 60 m path)."""
    start_jitter_m: Annotated[float, pydantic.Field(ge=0)] = 0.5
    """Half-width (m) of the uniform random offset of the start position on each world axis."""
    goal_radius_m: Annotated[float, pydantic.Field(gt=0)] = 1.0
    """Distance (m) to the goal that counts as reaching it."""
    random_start_prob: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.0
    """Probability that an episode starts at a random free point along the path instead of its
    start (training only: an ε-greedy agent rarely gets past the first obstacles, so it would
    never see the rest of a world). The moving setpoint starts level with that point."""
    random_start_clearance_m: Annotated[float, pydantic.Field(ge=0)] = 0.6
    """Least clearance (m) from any solid at a random start point (beyond the quad's radius)."""
    depth_history: Annotated[int, pydantic.Field(ge=1)] = 1
    """Depth inputs stacked in the observation (1 = the paper)."""
    position_history: Annotated[int, pydantic.Field(ge=1)] = 1
    """Relative positions stacked in the observation (1 = the paper)."""
    primitives: PrimitiveConfig = field(default_factory=PrimitiveConfig)
    """Motion primitives (scale 1 m, 1 s in simulation)."""
    reward: RewardParams = field(default_factory=RewardParams)
    """The paper's reward constants (deviation limit 5 m)."""
    quad: QuadParams = field(default_factory=QuadParams)
    """Kinematic quad: tracking response, limits, collision radius."""
    preprocess: PreprocessConfig = field(default_factory=PreprocessConfig)
    """Depth-to-input conversion, shared with the flight daemon."""
    shield: ShieldConfig = field(default_factory=ShieldConfig)
    """Depth safety filter (off = the paper): when on, ``allowed`` holds the primitives it lets
    the planner choose at the next decision."""
    shield_band: bool = False
    """The filter also keeps each world's deviation limit (``reward.max_deviation_m`` round its
    rough path, the episode's ``"deviation"`` stop) as known space, as a flight's filter keeps
    ``safety.max_deviation_m`` round the path it flies
    (:meth:`~quadnav_onboard.shield.ShieldConfig.with_band`). Ignored when ``shield`` has a band
    of its own or is off."""


_VEC3 = ("setpoint_world_m", "rel_pos_body_m")
"""The :class:`~quadnav_onboard.step.StepInputs` fields that are 3-vectors."""


class VecQuadNavEnv:
    """N navigation episodes stepped together; worlds sampled per episode from ``worlds``.

    Observations: ``depth`` float32 (N, k_d, 32, 32) in [0, 1] and ``rel_pos`` float32 (N, k_p, 3)
    (heading frame, m), oldest first. With ``autoreset`` a finished env starts a new episode at once
    and its last observation is in ``info["final_depth"]``/``info["final_rel_pos"]``; without it a
    finished env stays frozen (its rows keep their last values) until :meth:`reset`.
    All randomness (world choice, start jitter) comes from one seeded numpy Generator.
    """

    def __init__(
        self,
        worlds: Sequence[World],
        n_envs: int,
        seed: int,
        config: EnvConfig = EnvConfig(),
        autoreset: bool = True,
        world_weights: Sequence[float] | None = None,
    ) -> None:
        if not worlds:
            raise ValueError("VecQuadNavEnv needs at least one world")
        if n_envs < 1:
            raise ValueError(f"n_envs must be >= 1, got {n_envs}")
        self.worlds = list(worlds)
        self.n_envs = int(n_envs)
        self.config = config
        self.autoreset = autoreset
        self.prims = config.primitives.build()
        self._world_p: NDArray[np.float64] | None = None
        if world_weights is not None:
            self.set_world_weights(world_weights)
        self.rng = np.random.default_rng(seed)
        self._u = step_fractions(self.prims.duration_s, config.quad.dt_s)  # (K, 1)
        n, kd, kp = self.n_envs, config.depth_history, config.position_history
        self.world_idx = np.zeros(n, dtype=np.int64)
        self.pos_m = np.zeros((n, 3))
        self.vel_m_s = np.zeros((n, 3))
        self.cmd_pos_m = np.zeros((n, 3))
        self.cmd_vel_m_s = np.zeros((n, 3))
        self.steps = np.zeros(n, dtype=np.int64)
        self.episode_return = np.zeros(n)
        self.done = np.zeros(n, dtype=bool)
        self.depth = np.ones((n, kd, OUT_SIZE, OUT_SIZE), dtype=np.float32)
        self.rel = np.zeros((n, kp, 3), dtype=np.float32)
        self.memory = PointMemory(n, config.shield) if config.shield.enabled else None
        self._world_shields: list[ShieldConfig] | None = None
        """Each world's filter, its deviation band known (``shield_band``); None: one for all."""
        if self.memory is not None and config.shield_band and config.shield.band_waypoints_m is None:
            half = config.reward.max_deviation_m
            self._world_shields = [config.shield.with_band(w.path.waypoints_m, half) for w in self.worlds]
        self._floor_z = np.array([np.nan if w.floor_z_m is None else w.floor_z_m for w in self.worlds])
        """Each world's floor height (m; NaN: none), for the shield's ``known_floor``."""
        self.clearance_m = np.full((n, self.prims.n_actions), config.shield.search_radius_m)
        """Shield clearance (m) of every primitive at the next decision (cap if the shield is off)."""
        self.allowed = np.ones((n, self.prims.n_actions), dtype=bool)
        """Primitives the shield allows at the next decision (all if it is off)."""
        self._limits = EpisodeLimits(config.goal_radius_m, config.reward.max_deviation_m, config.max_steps)
        self.last_step: StepRecord | None = None
        """The last :meth:`step`'s record of the envs that ran (their ids: ``last_step_ids``)."""
        self.last_step_ids = np.zeros(0, dtype=np.int64)
        self._inputs = {f.name: np.zeros((n, 3) if f.name in _VEC3 else n)
                        for f in dataclasses.fields(StepInputs)}
        """Each env's inputs of its next step (the last step's end, or the episode's start)."""

    # -- per-world helpers ---------------------------------------------------------------------
    def world_shield(self, w: int) -> ShieldConfig:
        """The filter the vehicles in world ``w`` fly behind (with its deviation band, if known)."""
        return self.config.shield if self._world_shields is None else self._world_shields[w]

    def _groups(self, mask: NDArray[np.bool_]) -> list[tuple[World, NDArray[np.int64]]]:
        ids = np.flatnonzero(mask)
        return [(self.worlds[w], ids[self.world_idx[ids] == w]) for w in np.unique(self.world_idx[ids])]

    def _observe(self, ids: NDArray[np.int64], world: World, yaw: NDArray) -> DepthInputs:
        """The views of the quads ``ids``: the network inputs and, with the shield's
        ``depth_pooling: min``, its nearest-surface views and where in each cell they were seen."""
        shield = self.config.shield
        nearest = self.memory is not None and shield.depth_pooling == "min"
        return render_inputs(world, self.pos_m[ids], yaw, self.config.preprocess, nearest=nearest)

    def _update_shield(self, ids: NDArray[np.int64], view: DepthInputs, yaw: NDArray, new: bool) -> None:
        """Remember the new views of ``ids`` (:meth:`_observe`'s: the nearest surfaces, placed where
        they were seen, else the network inputs) and re-check every primitive for the next decision."""
        if self.memory is None:
            return
        if new:
            self.memory.clear(ids)
        depth = view.mean if view.near is None else view.near
        self.memory.add(ids, depth, self.pos_m[ids], yaw, view.near_at)
        mem = self.memory
        yaw = np.asarray(yaw)
        if self._world_shields is None:
            groups = [(self.config.shield, np.arange(len(ids)))]
        else:  # each world's band: one check per world among ``ids``
            w_of = self.world_idx[ids]
            groups = [(self._world_shields[w], np.flatnonzero(w_of == w)) for w in np.unique(w_of)]
        for shield, rows in groups:
            sel = ids[rows]
            self.allowed[sel], self.clearance_m[sel] = shield_verdict(
                self.prims, mem.points[sel], mem.depth_m[sel], mem.pose[sel], self.cmd_pos_m[sel],
                self.cmd_vel_m_s[sel], yaw[rows], self.pos_m[sel], self.vel_m_s[sel], shield,
                floor_z_m=self._floor_z[self.world_idx[sel]],
            )

    def _stop_at_contact(
        self, world: World, ids: NDArray[np.int64], collided: NDArray, trail: NDArray
    ) -> None:
        for j in np.flatnonzero(collided):
            hits = np.flatnonzero(collides(world, trail[:, j], self.config.quad.radius_m))
            if hits.size:
                self.pos_m[ids[j]] = trail[hits[0], j]
                self.vel_m_s[ids[j]] = 0.0

    def _random_starts(self, world: World, ids: NDArray[np.int64], tries: int = 8) -> None:
        """Move a random share of ``ids`` to free points along the path (see ``random_start_prob``).

        The step counter starts level with the point, so the moving setpoint is where it would be
        had the quad flown there on schedule; points too close to a solid are redrawn a few times,
        then the env keeps the path's start.
        """
        cfg, path = self.config, world.path
        chosen = ids[self.rng.random(ids.size) < cfg.random_start_prob]
        if chosen.size == 0:
            return
        step_m = path.speed_m_s * self.prims.duration_s
        arc = self.rng.uniform(0.0, 0.9 * path.length_m, size=(tries, chosen.size))
        jitter = self.rng.uniform(-1.0, 1.0, size=(tries, chosen.size, 3)) * cfg.start_jitter_m
        cand = path.point_at(arc) + jitter  # (tries, m, 3)
        free = clearance_m(world, cand.reshape(-1, 3)).reshape(tries, -1) > (
            cfg.quad.radius_m + cfg.random_start_clearance_m
        )
        first = np.argmax(free, axis=0)
        ok = free[first, np.arange(chosen.size)]
        pick = np.arange(chosen.size)[ok]
        self.pos_m[chosen[ok]] = cand[first[ok], pick]
        self.steps[chosen[ok]] = np.floor(arc[first[ok], pick] / step_m).astype(np.int64)

    # -- API -------------------------------------------------------------------------------------
    def set_world_weights(self, weights: Sequence[float] | NDArray) -> None:
        """From the next reset on, pick each episode's world in proportion to ``weights`` (one
        finite weight >= 0 per world, not all 0)."""
        p = np.asarray(weights, dtype=np.float64)
        if p.shape != (len(self.worlds),):
            raise ValueError(f"world weights: need {len(self.worlds)} (one per world), got shape {p.shape}")
        if not (np.isfinite(p).all() and (p >= 0).all() and p.sum() > 0):
            raise ValueError("world weights must be finite, >= 0 and not all 0")
        self._world_p = p / p.sum()

    def reset(self, mask: NDArray[np.bool_] | None = None) -> tuple[NDArray[np.float32], NDArray[np.float32]]:
        """Start new episodes in the envs of ``mask`` (all if None); returns the observations."""
        mask = np.ones(self.n_envs, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        ids = np.flatnonzero(mask)
        if ids.size == 0:
            return self.depth, self.rel
        m = ids.size
        self.world_idx[ids] = self.rng.choice(len(self.worlds), size=m, p=self._world_p)
        jitter = self.rng.uniform(-1.0, 1.0, size=(m, 3)) * self.config.start_jitter_m
        self.steps[ids] = 0
        for w in np.unique(self.world_idx[ids]):
            sel = ids[self.world_idx[ids] == w]
            self.pos_m[sel] = self.worlds[w].path.start_m + jitter[self.world_idx[ids] == w]
            if self.config.random_start_prob > 0.0:
                self._random_starts(self.worlds[w], sel)
        self.vel_m_s[ids] = 0.0
        self.cmd_pos_m[ids] = self.pos_m[ids]
        self.cmd_vel_m_s[ids] = 0.0
        self.episode_return[ids] = 0.0
        self.done[ids] = False
        for world, sel in self._groups(mask):
            first = step_inputs(world.path, self.steps[sel], self.prims.duration_s, self.pos_m[sel])
            self._keep_inputs(sel, first)
            view = self._observe(sel, world, first.yaw_rad)
            self.depth[sel] = view.mean[:, None]
            self.rel[sel] = first.rel_pos_body_m[:, None]
            self._update_shield(sel, view, first.yaw_rad, new=True)
        return self.depth, self.rel

    def step(self, actions: NDArray) -> tuple[NDArray, NDArray, NDArray, NDArray, NDArray, dict[str, Any]]:
        """Advance every running env by one primitive (:mod:`quadnav_onboard.step`).

        Returns ``(depth, rel_pos, reward (N,), terminated (N,), truncated (N,), info)``; ``info``
        holds arrays ``progress_m``, ``time_s``, ``deviation_m``, ``outcome`` (object: None or a
        string of :data:`OUTCOMES`), ``episode_return``, ``world_index``, ``steps`` and, with
        autoreset, ``final_depth``/``final_rel_pos``. :attr:`last_step` holds the step's
        :class:`~quadnav_onboard.step.StepRecord` of the envs that ran (``last_step_ids``).
        """
        actions = np.asarray(actions, dtype=np.int64).reshape(self.n_envs)
        run = ~self.done
        cfg, prims = self.config, self.prims
        n = self.n_envs
        rew = np.zeros(n)
        code = np.zeros(n, dtype=np.int8)
        progress = np.zeros(n)
        deviation = np.zeros(n)
        groups = self._groups(run)
        all_ids = np.flatnonzero(run)
        yaw0 = np.zeros(n)
        before: dict[int, StepInputs] = {}
        pos0 = self.pos_m.copy()
        for g, (_, ids) in enumerate(groups):  # the step's inputs: where the last step ended
            before[g] = StepInputs(**{k: v[ids] for k, v in self._inputs.items()})
            yaw0[ids] = before[g].yaw_rad
        # the primitive from the last commanded end point (C1); one batched dynamics call for all
        yaw = yaw0[all_ids]
        targets, target_vel = primitive_targets(
            prims, actions[all_ids], self.cmd_pos_m[all_ids], self.cmd_vel_m_s[all_ids], yaw, self._u
        )  # (K, m, 3)
        state, trail_all = track(
            QuadState(self.pos_m[all_ids], self.vel_m_s[all_ids]), targets, target_vel, cfg.quad
        )
        self.pos_m[all_ids] = state.pos_m
        self.vel_m_s[all_ids] = state.vel_m_s
        self.cmd_pos_m[all_ids] = targets[-1]
        self.cmd_vel_m_s[all_ids] = target_vel[-1]
        steps_before = self.steps.copy()
        self.steps[all_ids] += 1
        col = np.searchsorted(all_ids, np.arange(n))  # env id -> column in trail_all
        records = []
        for g, (world, ids) in enumerate(groups):
            trail = trail_all[:, col[ids]]
            collided = sweep_collides(world, trail, cfg.quad.radius_m)
            if collided.any():  # a crashed quad stops where it first touched
                self._stop_at_contact(world, ids, collided, trail)
            after = step_inputs(world.path, self.steps[ids], prims.duration_s, self.pos_m[ids])
            self._keep_inputs(ids, after)
            rec = finish_step(
                before[g], after, step=steps_before[ids], action=actions[ids], q_values=None,
                pos_world_m=pos0[ids], end_pos_world_m=self.pos_m[ids], collided=collided,
                path=world.path, limits=self._limits, reward_params=cfg.reward,
                shield_allowed=self.allowed[ids] if self.memory is not None else None,
                shield_clearance_m=self.clearance_m[ids] if self.memory is not None else None,
                n_actions=prims.n_actions,
            )
            records.append((ids, rec))
            code[ids] = rec.outcome
            rew[ids] = rec.reward
            progress[ids] = rec.progress_m
            deviation[ids] = rec.deviation_m
            view = self._observe(ids, world, after.yaw_rad)
            self.depth[ids] = push_history(self.depth[ids], view.mean)
            self.rel[ids] = push_history(self.rel[ids], after.rel_pos_body_m)
            self._update_shield(ids, view, after.yaw_rad, new=False)
        self._set_last_step(records)
        self.episode_return[run] += rew[run]
        terminated = run & (code >= Outcome.GOAL) & (code <= Outcome.DEVIATION)
        truncated = run & (code == Outcome.TIMEOUT)
        ended = terminated | truncated
        outcome = np.array([Outcome(c).label for c in code], dtype=object)
        info: dict[str, Any] = {
            "progress_m": progress,
            "time_s": self.steps * prims.duration_s,
            "deviation_m": deviation,
            "outcome": outcome,
            "episode_return": self.episode_return.copy(),
            "world_index": self.world_idx.copy(),
            "steps": self.steps.copy(),
        }
        self.done |= ended
        if self.autoreset:
            info["final_depth"] = self.depth.copy()
            info["final_rel_pos"] = self.rel.copy()
            info["final_allowed"] = self.allowed.copy()
            if ended.any():
                self.reset(ended)
        return self.depth, self.rel, rew, terminated, truncated, info

    def _keep_inputs(self, ids: NDArray[np.int64], inputs: StepInputs) -> None:
        for k, v in self._inputs.items():
            v[ids] = getattr(inputs, k)

    def _set_last_step(self, records: list[tuple[NDArray[np.int64], StepRecord]]) -> None:
        """One record of the step for every env that ran, in env order."""
        if not records:
            self.last_step, self.last_step_ids = None, np.zeros(0, dtype=np.int64)
            return
        ids = np.concatenate([i for i, _ in records])
        order = np.argsort(ids, kind="stable")
        merged = {}
        for f in dataclasses.fields(StepRecord):
            parts = [getattr(r, f.name) for _, r in records]
            merged[f.name] = None if parts[0] is None else np.concatenate(parts)[order]
        self.last_step, self.last_step_ids = StepRecord(**merged), ids[order]


def rel_pos_bound_m(worlds: Sequence[World], config: EnvConfig) -> float:
    """A bound (m) on every component of the position input in ``worlds``.

    The setpoint and the quad's closest path point both lie on the path, so they are at most the
    largest distance between two of its waypoints apart; the quad is within the deviation limit of
    the path (or its start offset), plus at most one primitive's travel at the speed limit on the
    step that ends an episode. 1 m of margin on top."""
    spread = 0.0
    for w in worlds:
        wp = np.asarray(w.path.waypoints_m, dtype=np.float64)
        spread = max(spread, float(np.linalg.norm(wp[:, None] - wp[None], axis=-1).max()))
    off_path = max(config.reward.max_deviation_m, math.sqrt(3.0) * config.start_jitter_m)
    step = config.quad.max_speed_m_s * config.primitives.duration_s
    return spread + off_path + step + 1.0


def observation_space(worlds: Sequence[World], config: EnvConfig) -> gym.spaces.Dict:
    """One env's observation: ``depth`` in [0, 1], ``rel_pos`` within :func:`rel_pos_bound_m`."""
    kd, kp = config.depth_history, config.position_history
    bound = rel_pos_bound_m(worlds, config)
    return gym.spaces.Dict(
        {
            "depth": gym.spaces.Box(0.0, 1.0, (kd, OUT_SIZE, OUT_SIZE), dtype=np.float32),
            "rel_pos": gym.spaces.Box(-bound, bound, (kp, 3), dtype=np.float32),
        }
    )


class QuadNavEnv(gym.Env):
    """Single-episode Gymnasium view of :class:`VecQuadNavEnv`.

    Observation ``Dict(depth=Box(0, 1, (k_d, 32, 32)), rel_pos=Box(-b, b, (k_p, 3)))`` with ``b``
    from :func:`rel_pos_bound_m` (m), action
    ``Discrete(n_actions)``; ``info``: ``progress_m`` (navigation distance), ``time_s``,
    ``deviation_m``, ``outcome`` and ``world_index``. ``reset(seed=s)`` re-seeds the Generator, so
    a seeded episode with the same actions is reproducible bit for bit.
    """

    metadata = {"render_modes": []}

    def __init__(self, worlds: Sequence[World], config: EnvConfig = EnvConfig(), seed: int = 0) -> None:
        super().__init__()
        self.config = config
        self._worlds = list(worlds)
        self._vec = VecQuadNavEnv(self._worlds, 1, seed, config, autoreset=False)
        self.observation_space = observation_space(self._worlds, config)
        self.action_space = gym.spaces.Discrete(self._vec.prims.n_actions)

    def _obs(self) -> dict[str, NDArray[np.float32]]:
        return {"depth": self._vec.depth[0].copy(), "rel_pos": self._vec.rel[0].copy()}

    def reset(self, *, seed: int | None = None, options: dict | None = None) -> tuple[dict, dict]:
        super().reset(seed=seed)
        if seed is not None:
            self._vec.rng = np.random.default_rng(seed)
        self._vec.reset()
        v = self._vec
        info = {"progress_m": 0.0, "time_s": 0.0, "outcome": None, "world_index": int(v.world_idx[0])}
        return self._obs(), info

    def step(self, action: int) -> tuple[dict, float, bool, bool, dict]:
        if self._vec.done[0]:
            raise RuntimeError("step() after the episode ended: call reset()")
        _, _, rew, term, trunc, info = self._vec.step(np.array([int(action)]))
        out = {
            "progress_m": float(info["progress_m"][0]),
            "time_s": float(info["time_s"][0]),
            "deviation_m": float(info["deviation_m"][0]),
            "outcome": info["outcome"][0],
            "world_index": int(info["world_index"][0]),
        }
        return self._obs(), float(rew[0]), bool(term[0]), bool(trunc[0]), out


REFERENCE_SCALE_M = 1.0
"""Primitive scale (m) that world files' path speeds and the 120-step limit are written for."""


def at_primitive_scale(
    env_config: EnvConfig, worlds: Sequence[World], scale_m: float, max_steps: int | None = None
) -> tuple[EnvConfig, list[World]]:
    """The env and worlds flown with primitives of ``scale_m`` metres per axis (a real flight: 0.5 m,
    as in the paper). Worlds and ``env_config.max_steps`` are taken as written for
    :data:`REFERENCE_SCALE_M`: each world's moving setpoint slows in proportion, so it still
    advances one primitive per step, and the step limit grows in proportion unless ``max_steps``
    is given. The shield, written for ``env_config``'s primitives, keeps the same distance of
    memory (:func:`quadnav_onboard.shield.shield_at_scale`)."""
    ratio = scale_m / REFERENCE_SCALE_M
    cfg = dataclasses.replace(
        env_config,
        primitives=dataclasses.replace(env_config.primitives, scale_m=scale_m),
        shield=shield_at_scale(env_config.shield, env_config.primitives.scale_m, scale_m),
        max_steps=max_steps if max_steps is not None else math.ceil(env_config.max_steps / ratio),
    )
    slowed = [
        dataclasses.replace(w, path=dataclasses.replace(w.path, speed_m_s=w.path.speed_m_s * ratio))
        for w in worlds
    ]
    return cfg, slowed


class QuadNavVectorEnv(gym.vector.VectorEnv):
    """Gymnasium 1.x ``VectorEnv`` over :class:`VecQuadNavEnv`: the same step, every env in one batch.

    ``autoreset_mode`` (``metadata["autoreset_mode"]``), Gymnasium's three:

    - ``NEXT_STEP`` (Gymnasium's default): an env that ends at step t returns its last observation
      at t; at step t+1 it starts a new episode and returns the first observation, reward 0, not
      terminated nor truncated, its action ignored.
    - ``SAME_STEP``: it starts the new episode at t; its last observation and info are in
      ``info["final_obs"]``/``info["final_info"]`` (masks ``_final_obs``/``_final_info``), as
      :class:`VecQuadNavEnv` itself does with ``autoreset``.
    - ``DISABLED``: a finished env stays as it ended until ``reset(options={"reset_mask": mask})``.

    Infos are Gymnasium's vector infos: ``progress_m``, ``time_s``, ``deviation_m``, ``outcome``,
    ``world_index``, each with its ``_key`` mask. One seeded Generator draws for every env:
    ``reset(seed=s)`` re-seeds it (a list of seeds: its first).
    """

    def __init__(
        self,
        worlds: Sequence[World],
        num_envs: int,
        config: EnvConfig = EnvConfig(),
        seed: int = 0,
        autoreset_mode: gym.vector.AutoresetMode | str = gym.vector.AutoresetMode.NEXT_STEP,
    ) -> None:
        self._vec = VecQuadNavEnv(list(worlds), num_envs, seed, config, autoreset=False)
        self.num_envs = int(num_envs)
        self.autoreset_mode = gym.vector.AutoresetMode(autoreset_mode)
        self.metadata = {"autoreset_mode": self.autoreset_mode, "render_modes": []}
        self.render_mode = None
        self.single_observation_space = observation_space(self._vec.worlds, config)
        self.single_action_space = gym.spaces.Discrete(self._vec.prims.n_actions)
        self.observation_space = gym.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = gym.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self._pending = np.zeros(self.num_envs, dtype=bool)
        """NEXT_STEP: envs that ended at the last step and start anew at the next."""

    @property
    def unwrapped_vec(self) -> VecQuadNavEnv:
        """The numpy batch stepped underneath."""
        return self._vec

    def _obs(self) -> dict[str, NDArray[np.float32]]:
        return {"depth": self._vec.depth.copy(), "rel_pos": self._vec.rel.copy()}

    def _infos(self, info: dict[str, Any] | None) -> dict[str, Any]:
        v, n = self._vec, self.num_envs
        if info is None:  # after a reset
            info = {"progress_m": np.zeros(n), "time_s": np.zeros(n), "deviation_m": np.zeros(n),
                    "outcome": np.full(n, None, dtype=object), "world_index": v.world_idx.copy()}
        out: dict[str, Any] = {}
        for key in ("progress_m", "time_s", "deviation_m", "outcome", "world_index"):
            out[key] = np.asarray(info[key]).copy()
            out[f"_{key}"] = np.ones(n, dtype=bool)
        return out

    def reset(
        self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, NDArray[np.float32]], dict[str, Any]]:
        if seed is not None:
            self._vec.rng = np.random.default_rng(seed[0] if isinstance(seed, list) else seed)
        mask = None if not options or options.get("reset_mask") is None else np.asarray(options["reset_mask"])
        self._vec.reset(mask)
        self._pending[slice(None) if mask is None else mask] = False
        return self._obs(), self._infos(None)

    def step(
        self, actions: NDArray
    ) -> tuple[dict[str, NDArray[np.float32]], NDArray, NDArray, NDArray, dict[str, Any]]:
        v, n = self._vec, self.num_envs
        restart = self._pending.copy()
        if (~v.done).any():
            _, _, rew, term, trunc, info = v.step(actions)
        else:  # every env finished: nothing steps
            rew, term, trunc = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
            info = self._infos(None)
        infos = self._infos(info)
        ended = term | trunc
        mode = self.autoreset_mode
        if mode == gym.vector.AutoresetMode.NEXT_STEP:
            if restart.any():
                v.reset(restart)
                for key in ("progress_m", "time_s", "deviation_m"):
                    infos[key][restart] = 0.0
                infos["world_index"][restart] = v.world_idx[restart]
            self._pending = ended.copy()
        elif mode == gym.vector.AutoresetMode.SAME_STEP and ended.any():
            final = self._obs()
            final_obs = np.full(n, None, dtype=object)
            final_info = np.full(n, None, dtype=object)
            for i in np.flatnonzero(ended):
                final_obs[i] = {k: a[i] for k, a in final.items()}
                final_info[i] = {k: infos[k][i] for k in ("progress_m", "time_s", "deviation_m", "outcome")}
            v.reset(ended)
            infos.update(final_obs=final_obs, _final_obs=ended.copy(), final_info=final_info,
                         _final_info=ended.copy())
        return self._obs(), rew.astype(np.float64), term.copy(), trunc.copy(), infos


ENV_ID = "quadnav/QuadNav-v0"
"""The Gymnasium id of the navigation env (registered when this module is imported)."""

WorldSpec = World | str | Path | int
"""A world: loaded, a world file's path, or a paper world id (1-10)."""


def _worlds(world: WorldSpec | Sequence[WorldSpec] | None) -> list[World]:
    """The worlds ``world`` names (default: the paper's training worlds 1-7)."""
    if world is None:
        world = list(range(1, 8))
    items = [world] if isinstance(world, World | str | Path | int) else list(world)
    out = []
    for w in items:
        if isinstance(w, World):
            out.append(w)
        elif isinstance(w, int) and not isinstance(w, bool):
            out.append(load_world(paper_world_path(w)))
        else:
            out.append(load_world(Path(w)))
    if not out:
        raise ValueError("world: at least one world")
    return out


def _limit_sim_threads(sim_threads: int | None) -> None:
    if sim_threads:
        import numba

        numba.set_num_threads(min(sim_threads, numba.config.NUMBA_NUM_THREADS))


def make_env(
    world: WorldSpec | Sequence[WorldSpec] | None = None,
    config: EnvConfig = EnvConfig(),
    seed: int = 0,
    sim_threads: int | None = 1,
) -> QuadNavEnv:
    """``gymnasium.make("quadnav/QuadNav-v0", world=...)``: one env over ``world`` (a world, a world
    file, a paper world id, or a list of them; default: paper worlds 1-7).

    ``sim_threads``: numba threads of the env's kernels (None leaves numba's setting). One: a single
    env's kernels are too small to share, and a learner in the same process needs the other cores
    (sim_harness.rl.threads)."""
    _limit_sim_threads(sim_threads)
    return QuadNavEnv(_worlds(world), config, seed)


def make_vector_env(
    num_envs: int,
    world: WorldSpec | Sequence[WorldSpec] | None = None,
    config: EnvConfig = EnvConfig(),
    seed: int = 0,
    autoreset_mode: gym.vector.AutoresetMode | str = gym.vector.AutoresetMode.NEXT_STEP,
    sim_threads: int | None = 1,
) -> QuadNavVectorEnv:
    """``gymnasium.make_vec("quadnav/QuadNav-v0", num_envs=N, world=...)``: a
    :class:`QuadNavVectorEnv` (arguments as :func:`make_env`)."""
    _limit_sim_threads(sim_threads)
    return QuadNavVectorEnv(_worlds(world), num_envs, config, seed, autoreset_mode)


if ENV_ID not in gym.registry:
    gym.register(
        id=ENV_ID,
        entry_point="sim_harness.env:make_env",
        vector_entry_point="sim_harness.env:make_vector_env",
        max_episode_steps=None,  # the env truncates at EnvConfig.max_steps itself
    )
