"""Greedy evaluation: the paper's table (per world and trial) and its summary rates.

Each world runs its ``trials`` episodes together in one :class:`VecQuadNavEnv` (no auto-reset);
trials differ by their seeded start jitter. Rows hold the paper's columns (navigation distance m,
navigation time s, crash Y/N, total reward) plus the outcome. ``summarize`` counts success (goal),
collision-free flights and success among the collision-free ones.

A world's known room (its walls and ceiling, :meth:`sim_harness.world.World.room_box_m`) is given
to the depth safety filter as known space, as the floor already is. Flown under a flight config
(:func:`flight_eval_setup`), the eval also stops a flight as the flight supervisor would on the
config's geofence and altitude band (outcomes ``geofence`` and ``altitude``: safe, not a goal;
checked at each step's end, where the supervisor checks at 50 Hz), intersects the geofence into
the filter's room, and renders with the D435-like depth noise (:mod:`sim_harness.noise`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.path import RoughPath
from quadnav_onboard.policy import Policy, masked_argmax
from quadnav_onboard.preprocess import DepthInputs, depth_inputs_mm
from quadnav_onboard.shield import ShieldConfig, shield_at_scale, shield_config_from_meta
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.noise import DepthNoise, apply_depth_noise, noise_at_width
from sim_harness.render import D435_424x240, render_input_frames_mm
from sim_harness.world import WORLD_LIMIT_M, World

if TYPE_CHECKING:
    from quadnav_onboard.daemon.config import FlightConfig

__all__ = [
    "EvalRow",
    "FlightLimits",
    "GreedyFn",
    "NoisyDepthEnv",
    "PolicyGreedy",
    "StepHook",
    "env_config_for_policy",
    "eval_starts",
    "evaluate",
    "flight_eval_setup",
    "flight_setup_for",
    "format_table",
    "known_room",
    "override_shield",
    "policy_greedy_fn",
    "scores",
    "summarize",
    "world_seed",
]

GreedyFn = Callable[[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]], NDArray[np.int64]]
"""Batched policy: depth (B, k_d, 32, 32), rel (B, k_p, 3), allowed (B, n_actions) -> actions (B,).
``allowed`` is the shield's verdict (all True when the shield is off)."""

StepHook = Callable[[World, VecQuadNavEnv, NDArray[np.float32], NDArray[np.float32], NDArray[np.int64]], None]
"""``evaluate``'s ``on_step``: (world, env, depth, rel, actions) before each step of a world's env."""


@dataclasses.dataclass(frozen=True)
class EvalRow:
    """One trial of one world: the paper's columns and the outcome."""

    world: str
    """World name."""
    trial: int
    """Trial index, 0-based."""
    distance_m: float
    """Navigation distance (m): progress along the path at the end."""
    time_s: float
    """Navigation time (s): steps x primitive duration."""
    crash: bool
    """A collision ended the flight."""
    total_reward: float
    """Sum of the paper's rewards over the flight."""
    outcome: str
    """goal | crash | deviation | timeout, and under a flight config geofence | altitude."""
    start_m: tuple[float, float, float] | None = None
    """Where the flight started (world frame, m, the start jitter included): with the primitives'
    fixed steps it sets every position the vehicle can reach, such as its heights at 1 m."""

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["crash"] = "Y" if self.crash else "N"
        return d


def env_config_for_policy(
    policy: Policy, max_steps: int = 120, start_jitter_m: float = 0.5, shield: ShieldConfig | None = None
) -> EnvConfig:
    """The env the policy was trained for: its history lengths, primitives, preprocessing and
    shield (``shield`` overrides the checkpoint's)."""
    prims = parse_config(PrimitiveConfig, policy.checkpoint.primitives, source="checkpoint.primitives")
    if shield is None:
        shield = shield_config_from_meta(policy.checkpoint.meta)
    return EnvConfig(
        shield=shield,
        max_steps=max_steps,
        start_jitter_m=start_jitter_m,
        depth_history=policy.depth_history,
        position_history=policy.position_history,
        primitives=prims,
        preprocess=policy.preprocess_config(),
    )


def override_shield(shield: ShieldConfig, pairs: Sequence[str]) -> ShieldConfig:
    """``shield`` with ``KEY=VALUE`` overrides (values in YAML), validated like a config file:
    errors name the key (``--shield-set`` of eval and select)."""
    import yaml

    data = dataclasses.asdict(shield)
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep:
            raise ValueError(f"--shield-set {pair!r}: expected KEY=VALUE")
        data[key.strip()] = yaml.safe_load(value)
    return parse_config(ShieldConfig, data, source="--shield-set")


@dataclasses.dataclass(frozen=True)
class FlightLimits:
    """A flight config's stop conditions the eval applies itself (the supervisor's, in flight)."""

    geofence_min_m: tuple[float, float, float]
    """Lowest corner (world, m) of the geofence."""
    geofence_max_m: tuple[float, float, float]
    """Highest corner (world, m) of the geofence."""
    altitude_floor_m: float
    """Lowest allowed height (world z, m)."""
    altitude_ceiling_m: float
    """Highest allowed height (world z, m)."""
    max_deviation_m: float | None = None
    """The flight's deviation limit (m from the rough path), a stop the filter keeps clear of as
    known space (:meth:`~quadnav_onboard.shield.ShieldConfig.with_band`); None: not known to it."""

    def stop(self, pos_world_m: NDArray[np.float64]) -> NDArray[np.object_]:
        """Per position (N, 3): ``"geofence"``, ``"altitude"`` or None (inside both)."""
        p = np.asarray(pos_world_m, dtype=np.float64)
        out = np.full(p.shape[0], None, dtype=object)
        z = p[:, 2]
        out[(z < self.altitude_floor_m) | (z > self.altitude_ceiling_m)] = "altitude"
        lo, hi = np.asarray(self.geofence_min_m), np.asarray(self.geofence_max_m)
        out[((p < lo) | (p > hi)).any(axis=1)] = "geofence"
        return out


def known_room(shield: ShieldConfig, world: World, limits: FlightLimits | None = None) -> ShieldConfig:
    """``shield`` knowing ``world``'s room: its walls, floor and ceiling as solid faces
    (:meth:`~quadnav_onboard.shield.ShieldConfig.with_room`; a world without walls: its ceiling),
    the geofence of ``limits`` as the box the centre must stay in, and their deviation limit round
    ``world``'s path as the band it must stay in (:meth:`~quadnav_onboard.shield.ShieldConfig.with_band`)."""
    big = WORLD_LIMIT_M
    room = world.room_box_m()
    if room is None and world.ceiling_z_m is not None:
        floor = world.floor_z_m if world.floor_z_m is not None else -big
        room = ((-big, -big, floor), (big, big, world.ceiling_z_m))
    if room is not None:
        shield = shield.with_room(*room)
    if limits is not None:
        shield = shield.with_fence(limits.geofence_min_m, limits.geofence_max_m)
        shield = shield.with_band(world.path.waypoints_m, limits.max_deviation_m)
    return shield


def flight_eval_setup(
    policy: Policy, flight: FlightConfig, worlds: Sequence[World], start_jitter_m: float | None = None
) -> tuple[EnvConfig, list[World], FlightLimits]:
    """The env, worlds and stop conditions of ``flight``'s mission flown in ``worlds`` by
    ``policy``: :func:`flight_setup_for` from the env the checkpoint was trained for."""
    shield = shield_config_from_meta(policy.checkpoint.meta)
    base = env_config_for_policy(policy, shield=shield)
    return flight_setup_for(base, flight, worlds, start_jitter_m)


def flight_setup_for(
    trained: EnvConfig, flight: FlightConfig, worlds: Sequence[World], start_jitter_m: float | None = None
) -> tuple[EnvConfig, list[World], FlightLimits]:
    """The env, worlds and stop conditions of ``flight``'s mission flown in ``worlds`` by a network
    trained in ``trained``: the flight's primitives (else the trained ones), filter (else the
    trained one, its memory kept in distance flown), moving-setpoint speed, step limit, goal
    radius, deviation limit, geofence and altitude band; its waypoints (when set) replace each
    world's path, as in a dry run. The start jitter defaults to the mission's
    ``start_tolerance_m`` (where the flight begins); every flight starts at the path's start."""
    m, s = flight.mission, flight.safety
    prims = flight.primitives or trained.primitives
    shield = flight.shield if flight.shield is not None else trained.shield
    # as the flight's decider does
    shield = shield_at_scale(shield, trained.primitives.scale_m, prims.scale_m)
    env_cfg = dataclasses.replace(
        trained,
        max_steps=m.max_steps,
        start_jitter_m=m.start_tolerance_m if start_jitter_m is None else start_jitter_m,
        random_start_prob=0.0,
        shield=shield,
        primitives=prims,
        goal_radius_m=m.goal_radius_m,
        reward=dataclasses.replace(trained.reward, max_deviation_m=s.max_deviation_m),
    )
    flown = []
    for w in worlds:
        path = (
            RoughPath(np.asarray(m.waypoints_m, dtype=np.float64), m.speed_m_s)
            if m.waypoints_m is not None
            else dataclasses.replace(w.path, speed_m_s=m.speed_m_s)
        )
        flown.append(dataclasses.replace(w, path=path))
    limits = FlightLimits(
        tuple(s.geofence_min_m), tuple(s.geofence_max_m), s.altitude_floor_m, s.altitude_ceiling_m,
        s.max_deviation_m,
    )
    return env_cfg, flown, limits


class NoisyDepthEnv(VecQuadNavEnv):
    """The env with the D435-like noise model on the sim camera's frames before preprocessing (at
    their width: :func:`sim_harness.noise.noise_at_width`)."""

    def __init__(self, *args: Any, noise: DepthNoise, noise_seed: int, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._noise = noise
        self._noise_rng = np.random.default_rng(noise_seed)

    def _observe(self, ids: NDArray[np.int64], world: World, yaw: NDArray) -> DepthInputs:
        shield = self.config.shield
        nearest = self.memory is not None and shield.depth_pooling == "min"
        frames = render_input_frames_mm(world, self.pos_m[ids], yaw)
        cam = D435_424x240
        noise = noise_at_width(self._noise, frames.shape[-1], cam.width)
        noisy_m = apply_depth_noise(frames.astype(np.float32) / 1000.0, noise, self._noise_rng,
                                    max_range_m=cam.max_range_m)
        noisy_mm = np.round(noisy_m * 1000.0).clip(0, 65535).astype(np.uint16)
        return depth_inputs_mm(noisy_mm, self.config.preprocess, nearest=nearest)


class PolicyGreedy:
    """A :class:`Policy` as a batched greedy policy (a :data:`GreedyFn`). A model that reads the
    primitive scale it flies at (:attr:`Policy.reads_scale`) needs it: :func:`evaluate` hands each
    world's to :meth:`at_scale`, from the env config it flies."""

    def __init__(self, policy: Policy, scale_m: float | None = None) -> None:
        self.policy = policy
        self.scale_m = scale_m

    def at_scale(self, scale_m: float) -> PolicyGreedy:
        return PolicyGreedy(self.policy, scale_m)

    def __call__(self, depth: NDArray[np.float32], rel: NDArray[np.float32],
                 allowed: NDArray[np.bool_]) -> NDArray[np.int64]:
        return masked_argmax(self.policy.q_values_batch(depth, rel, self.scale_m), allowed)


def policy_greedy_fn(policy: Policy) -> PolicyGreedy:
    return PolicyGreedy(policy)


@dataclasses.dataclass
class FilterOverrules:
    """How often the depth safety filter overruled the DQN's first choice (its arg-max over every
    primitive) in an evaluation's decisions."""

    decisions: int = 0
    """Decisions taken with the filter on."""
    overruled: int = 0
    """Of those, decisions whose unmasked arg-max the filter vetoed."""

    @property
    def rate(self) -> float:
        return self.overruled / self.decisions if self.decisions else 0.0

    def to_dict(self) -> dict[str, float | int]:
        return {"decisions": self.decisions, "overruled": self.overruled, "rate": self.rate}


def world_seed(seed: int, index: int) -> int:
    """The seed of the flights in world ``index`` (from 0) of an eval's list: its starts and its
    depth noise depend on its place in the list and ``seed``, not on the other worlds."""
    return seed * 1009 + index


def _world_env(
    world: World, index: int, trials: int, seed: int, env_config: EnvConfig,
    limits: FlightLimits | None, depth_noise: DepthNoise | None, known_rooms: bool,
) -> VecQuadNavEnv:
    """The env :func:`evaluate` flies world ``index`` of its list in (not yet reset)."""
    cfg = env_config
    if known_rooms and cfg.shield.enabled:
        cfg = dataclasses.replace(cfg, shield=known_room(cfg.shield, world, limits))
    w_seed = world_seed(seed, index)
    if depth_noise is None:
        return VecQuadNavEnv([world], trials, seed=w_seed, config=cfg, autoreset=False)
    return NoisyDepthEnv([world], trials, seed=w_seed, config=cfg, autoreset=False,
                         noise=depth_noise, noise_seed=w_seed + 7919)


def eval_starts(
    world: World, index: int, trials: int, seed: int, env_config: EnvConfig,
    limits: FlightLimits | None = None, depth_noise: DepthNoise | None = None,
) -> NDArray[np.float64]:
    """Where the ``trials`` flights of :func:`evaluate` in world ``index`` of its list start (trials, 3)."""
    env = _world_env(world, index, trials, seed, env_config, limits, depth_noise, True)
    env.reset()
    return env.pos_m.copy()


def evaluate(
    act: GreedyFn,
    worlds: Sequence[World],
    trials: int,
    seed: int,
    env_config: EnvConfig = EnvConfig(),
    on_world_done: Callable[[World], None] | None = None,
    *,
    limits: FlightLimits | None = None,
    depth_noise: DepthNoise | None = None,
    known_rooms: bool = True,
    overrules: FilterOverrules | None = None,
    on_step: StepHook | None = None,
    on_world_start: Callable[[World, VecQuadNavEnv], None] | None = None,
) -> list[EvalRow]:
    """Fly ``trials`` greedy episodes in each world; rows in world order, then trial order.

    World ``i`` of ``worlds`` is flown with seed :func:`world_seed` ``(seed, i)``.

    ``limits``: a flight config's geofence and altitude band, checked at each step's end (outcomes
    ``geofence``/``altitude``) and, with ``known_rooms``, the geofence given to the filter with the
    world's room (:func:`known_room`). ``depth_noise``: the D435-like noise on every frame.
    ``overrules``: counts the decisions where the filter vetoed the DQN's first choice (costs one
    more network pass per step when the filter is on). ``on_step``: called before every step with
    the world, its env, the inputs the policy saw and the actions about to be flown (a trace).
    ``on_world_start``: called with each world and its env once the env is reset, before the
    first decision (a planner that reads the env's state, such as the privileged teacher)."""
    rows: list[EvalRow] = []
    for w_i, world in enumerate(worlds):
        env = _world_env(world, w_i, trials, seed, env_config, limits, depth_noise, known_rooms)
        cfg = env.config
        step_act = act.at_scale(cfg.primitives.scale_m) if isinstance(act, PolicyGreedy) else act
        depth, rel = env.reset()
        starts = np.round(env.pos_m.astype(np.float64), 3)
        if on_world_start is not None:
            on_world_start(world, env)
        outcome = np.full(trials, None, dtype=object)
        progress = np.zeros(trials)
        while not env.done.all():
            running = ~env.done
            actions = step_act(depth, rel, env.allowed)
            if overrules is not None and cfg.shield.enabled:
                first = step_act(depth, rel, np.ones_like(env.allowed))
                overrules.decisions += int(running.sum())
                overrules.overruled += int((running & (first != actions)).sum())
            if on_step is not None:
                on_step(world, env, depth, rel, actions)
            depth, rel, _, term, trunc, info = env.step(actions)
            ended = term | trunc
            outcome[ended] = info["outcome"][ended]
            progress[ended] = info["progress_m"][ended]
            if limits is not None:
                stop = limits.stop(env.pos_m)
                hit = running & ~ended & (stop != None)  # noqa: E711 (object array)
                outcome[hit] = stop[hit]
                progress[hit] = info["progress_m"][hit]
                env.done[hit] = True
        for t in range(trials):
            rows.append(
                EvalRow(
                    world=world.name,
                    trial=t,
                    distance_m=round(float(progress[t]), 2),
                    time_s=float(env.steps[t] * env.prims.duration_s),
                    crash=outcome[t] == "crash",
                    total_reward=round(float(env.episode_return[t]), 3),
                    outcome=str(outcome[t]),
                    start_m=(float(starts[t, 0]), float(starts[t, 1]), float(starts[t, 2])),
                )
            )
        if on_world_done is not None:
            on_world_done(world)
    return rows


def summarize(rows: Sequence[EvalRow]) -> dict[str, float | int]:
    """Success rate, collision-free rate and success among collision-free flights (fractions)."""
    n = len(rows)
    goals = sum(r.outcome == "goal" for r in rows)
    safe = sum(not r.crash for r in rows)
    safe_goals = sum(r.outcome == "goal" and not r.crash for r in rows)
    return {
        "trials": n,
        "goal": goals,
        "collision_free": safe,
        "success_rate": goals / n if n else 0.0,
        "collision_free_rate": safe / n if n else 0.0,
        "success_among_safe": safe_goals / safe if safe else 0.0,
    }


def scores(rows: Sequence[EvalRow]) -> dict[str, float]:
    """Flat scores of an evaluation (what TensorBoard and a sweep's scheduler read): goal and
    collision-free rates, mean navigation distance (m) and mean total reward."""
    s = summarize(rows)
    n = max(len(rows), 1)
    return {
        "goal_rate": round(float(s["success_rate"]), 6),
        "collision_free_rate": round(float(s["collision_free_rate"]), 6),
        "distance_m": round(sum(r.distance_m for r in rows) / n, 3),
        "reward": round(sum(r.total_reward for r in rows) / n, 4),
    }


def format_table(rows: Sequence[EvalRow]) -> str:
    """The paper's table as text, one line per trial, a rule between worlds."""
    head = (
        f"{'world':<22} {'trial':>5} {'distance (m)':>12} {'time (s)':>8} {'crash':>5} {'reward':>8}  outcome"
    )
    lines = [head, "-" * len(head)]
    prev = None
    for r in rows:
        if prev is not None and r.world != prev:
            lines.append("-" * len(head))
        prev = r.world
        lines.append(
            f"{r.world:<22} {r.trial:>5} {r.distance_m:>12.2f} {r.time_s:>8.0f} {'Y' if r.crash else 'N':>5} "
            f"{r.total_reward:>8.2f}  {r.outcome}"
        )
    return "\n".join(lines)
