"""One planner step, for N vehicles at once: the code training and flight both run.

A step k (k = 0, 1, ...) of a vehicle on a rough path:

1. **Inputs** (:func:`step_inputs`): the moving setpoint is ``path.setpoint_at(k * duration_s)``;
   the heading frame is the path's yaw at the vehicle's progress (its closest path point); the
   network's position input is the setpoint minus the vehicle in that frame.
2. **Decision**: the policy (and the depth safety filter) picks one primitive (not here: the
   training agent or :class:`quadnav_onboard.daemon.decide.Decider`).
3. **Rollout** (:func:`primitive_targets`): the primitive starts at the previous primitive's
   *commanded* end point with the previous commanded end velocity (C1 joins), in the heading frame.
4. **Outcome** (:func:`outcome_codes`), in this order: a collision ends it ("crash"), then a
   deviation past the episode's limit ("deviation"), then the goal ("goal": within the goal
   radius, or progress at the path's end), then the step limit ("timeout").
5. **Reward**: the paper's (:func:`quadnav_onboard.reward.reward`) from the setpoint distance at
   the start and end of the step.
6. **History** (:func:`push_history`): the newest depth and position inputs replace the oldest.

:func:`finish_step` turns the inputs at both ends of a step, the decision and what happened into
one :class:`StepRecord`: the training env returns one for its N envs, the flight daemon one with
N = 1 that the stop ladder, the flight recorder and the record reader use.

Positions world frame (x forward, y left, z up), metres; velocities m/s; yaw rad; times s.
"""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.frames import body_to_world, world_to_body
from quadnav_onboard.path import RoughPath
from quadnav_onboard.primitives import PrimitiveSet, bezier_position, bezier_velocity
from quadnav_onboard.reward import RewardParams, reward

__all__ = [
    "OUTCOMES",
    "EpisodeLimits",
    "Outcome",
    "StepInputs",
    "StepRecord",
    "finish_step",
    "goal_reached",
    "outcome_codes",
    "primitive_targets",
    "push_history",
    "step_fractions",
    "step_inputs",
]


class Outcome(enum.IntEnum):
    """How a step ended an episode (``RUNNING``: it did not). Lower codes are checked later:
    :func:`outcome_codes` lets a crash win over a deviation, a deviation over the goal, and the goal
    over the step limit."""

    RUNNING = 0
    GOAL = 1
    CRASH = 2
    DEVIATION = 3
    TIMEOUT = 4

    @property
    def label(self) -> str | None:
        """The outcome's name in evaluation results and records ("goal", ...); None while running."""
        return None if self is Outcome.RUNNING else self.name.lower()


OUTCOMES: tuple[str, ...] = tuple(o.name.lower() for o in Outcome if o is not Outcome.RUNNING)
"""Why an episode ends, in code order: ``("goal", "crash", "deviation", "timeout")``."""


@dataclass(frozen=True)
class EpisodeLimits:
    """When a step ends an episode (besides a collision)."""

    goal_radius_m: float
    """Distance (m) to the goal that counts as reaching it."""
    episode_deviation_m: float
    """Distance (m) from the path past which the episode ends with the paper's deviation penalty
    (the reward's ``max_deviation_m``; not the flight's safety limit, which stops a flight)."""
    max_steps: int
    """Steps after which the episode ends ("timeout")."""


@dataclass(frozen=True)
class StepInputs:
    """The planner's inputs at a step boundary, for N vehicles on one path (arrays, leading N)."""

    setpoint_world_m: NDArray[np.float64]
    """Moving setpoint (world, m), (N, 3)."""
    yaw_rad: NDArray[np.float64]
    """Heading (world yaw, rad) of the step's heading frame, (N,)."""
    rel_pos_body_m: NDArray[np.float64]
    """Setpoint minus vehicle in the heading frame (m), (N, 3): the network's position input."""
    distance_m: NDArray[np.float64]
    """|setpoint - vehicle| (m), (N,): the reward's d_t."""
    progress_m: NDArray[np.float64]
    """Arc length (m) of the vehicle's closest path point, (N,)."""
    deviation_m: NDArray[np.float64]
    """Distance (m) from the vehicle to the path, (N,)."""
    goal_distance_m: NDArray[np.float64]
    """Distance (m) from the vehicle to the goal, (N,)."""


def step_inputs(path: RoughPath, k: ArrayLike, duration_s: float, pos_world_m: ArrayLike) -> StepInputs:
    """Inputs of step ``k`` ((N,) or scalar) for vehicles at ``pos_world_m`` ((N, 3) or (3,)).

    The result always has a leading N (1 for a single position)."""
    pos = np.atleast_2d(np.asarray(pos_world_m, dtype=np.float64))
    steps = np.broadcast_to(np.asarray(k), (pos.shape[0],))
    arc, dev = path.closest(pos)
    yaw = path.yaw_at(arc)
    sp = path.setpoint_at(steps * duration_s)
    return StepInputs(
        setpoint_world_m=sp,
        yaw_rad=yaw,
        rel_pos_body_m=path.relative_state(sp, pos, yaw),
        distance_m=np.linalg.norm(sp - pos, axis=-1),
        progress_m=arc,
        deviation_m=dev,
        goal_distance_m=np.linalg.norm(path.goal_m - pos, axis=-1),
    )


def goal_reached(path: RoughPath, inputs: StepInputs, goal_radius_m: float) -> NDArray[np.bool_]:
    """Within ``goal_radius_m`` of the goal, or progress at (or past) the path's length; (N,)."""
    return (inputs.goal_distance_m <= goal_radius_m) | (inputs.progress_m >= path.length_m - 1e-9)


def primitive_targets(
    prims: PrimitiveSet,
    actions: ArrayLike,
    start_world_m: ArrayLike,
    start_vel_world_m_s: ArrayLike,
    yaw_rad: ArrayLike,
    u: ArrayLike,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The commanded primitives of N vehicles, sampled at fractions ``u`` of the step.

    ``actions`` (N,), ``start_world_m``/``start_vel_world_m_s`` (N, 3): the commanded start (the
    previous primitive's commanded end) and its velocity, world frame; ``yaw_rad`` (N,): the
    heading frame the primitives are expressed in; ``u`` (K, 1) in [0, 1]. Returns positions (world,
    m) and velocities (world, m/s), each (K, N, 3)."""
    yaw = np.asarray(yaw_rad, dtype=np.float64)
    v0 = world_to_body(np.asarray(start_vel_world_m_s, dtype=np.float64), yaw)
    ctrl = prims.control_points(np.asarray(actions, dtype=np.int64), v0)  # (N, 4, 3)
    pos = np.asarray(start_world_m, dtype=np.float64) + body_to_world(bezier_position(ctrl, u), yaw)
    vel = body_to_world(bezier_velocity(ctrl, u, prims.duration_s), yaw)
    return pos, vel


def step_fractions(duration_s: float, dt_s: float) -> NDArray[np.float64]:
    """The fractions ``u`` (K, 1) of a step at which a primitive of ``duration_s`` is flown with a
    tracking step of ``dt_s``: ``1/K, 2/K, ..., 1``, K = ``round(duration_s / dt_s)``, at least 1."""
    k = max(1, round(duration_s / dt_s))
    return (np.arange(1, k + 1, dtype=np.float64) / k)[:, None]


def outcome_codes(
    collided: ArrayLike, deviated: ArrayLike, goal: ArrayLike, timeout: ArrayLike
) -> NDArray[np.int8]:
    """:class:`Outcome` codes (N,) int8: the first true reason in the documented order wins."""
    code = np.zeros(np.shape(collided), dtype=np.int8)
    code = np.where(timeout, Outcome.TIMEOUT, code)
    code = np.where(goal, Outcome.GOAL, code)
    code = np.where(deviated, Outcome.DEVIATION, code)
    return np.where(collided, Outcome.CRASH, code).astype(np.int8)


def push_history(stack: NDArray, newest: ArrayLike) -> NDArray:
    """The history ``stack`` (N, k, ...) with ``newest`` (N, ...) appended and the oldest dropped
    (a new array; oldest first)."""
    new = np.asarray(newest, dtype=stack.dtype)
    return np.concatenate([stack[:, 1:], new[:, None]], axis=1)


@dataclass(frozen=True)
class StepRecord:
    """What one executed planner step did, for N vehicles (arrays with a leading N; N = 1 in
    flight). The one record of a step: the training env returns it, the flight daemon's stop ladder
    and recorder take it, and the record schema's ``quadnav.Step`` fields are these."""

    step: NDArray[np.int64]
    """Step index k (0-based), (N,)."""
    action: NDArray[np.int64]
    """Chosen primitive, (N,)."""
    q_values: NDArray[np.float64]
    """Q-values of the decision, (N, n_actions); NaN where none were computed."""
    rel_pos_body_m: NDArray[np.float64]
    """The network's position input: setpoint minus vehicle in the heading frame (m), (N, 3)."""
    moving_setpoint_world_m: NDArray[np.float64]
    """Moving setpoint at the decision (world, m), (N, 3)."""
    pos_world_m: NDArray[np.float64]
    """Vehicle position at the decision (world, m), (N, 3)."""
    yaw_rad: NDArray[np.float64]
    """Heading of the step's frame (world yaw, rad), (N,)."""
    end_pos_world_m: NDArray[np.float64]
    """Vehicle position at the end of the step (world, m), (N, 3)."""
    d_prev_m: NDArray[np.float64]
    """Setpoint distance (m) at the decision, (N,)."""
    d_now_m: NDArray[np.float64]
    """Distance (m) from the vehicle at the end of the step to the next step's setpoint, (N,)."""
    progress_m: NDArray[np.float64]
    """Progress along the path (m) at the end of the step, (N,)."""
    deviation_m: NDArray[np.float64]
    """Distance from the path (m) at the end of the step, (N,)."""
    deviated: NDArray[np.bool_]
    """Deviation past the episode's limit at the end of the step, (N,)."""
    collided: NDArray[np.bool_]
    """A collision during the step, (N,)."""
    reward: NDArray[np.float64]
    """The paper's reward for the step, (N,)."""
    outcome: NDArray[np.int8]
    """:class:`Outcome` code (0: the episode goes on), (N,)."""
    shield_allowed: NDArray[np.bool_] | None
    """Primitives the depth safety filter allowed at the decision, (N, n_actions); None: off."""
    shield_clearance_m: NDArray[np.float64] | None
    """The filter's clearance (m) of every primitive at the decision, (N, n_actions); None: off."""

    @property
    def n(self) -> int:
        """Vehicles in the record."""
        return int(self.step.shape[0])

    def row(self, i: int) -> StepRecord:
        """Vehicle ``i`` alone (N = 1)."""
        sel = slice(i, i + 1)
        rows = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return StepRecord(**{k: None if v is None else v[sel] for k, v in rows.items()})

    def outcome_label(self, i: int = 0) -> str | None:
        """Vehicle ``i``'s outcome as a name ("goal", ...), None while the episode goes on."""
        return Outcome(int(self.outcome[i])).label

    def as_dict(self, i: int = 0) -> dict[str, Any]:
        """Vehicle ``i``'s step as plain Python values (lists, floats, ints, bools, None)."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            v = getattr(self, f.name)
            out[f.name] = None if v is None else np.asarray(v[i]).tolist()
        return out


def finish_step(
    before: StepInputs,
    after: StepInputs,
    *,
    step: ArrayLike,
    action: ArrayLike,
    q_values: ArrayLike | None,
    pos_world_m: ArrayLike,
    end_pos_world_m: ArrayLike,
    collided: ArrayLike,
    path: RoughPath,
    limits: EpisodeLimits,
    reward_params: RewardParams,
    shield_allowed: ArrayLike | None = None,
    shield_clearance_m: ArrayLike | None = None,
    n_actions: int | None = None,
) -> StepRecord:
    """The record of a step that started at ``before`` (its inputs, step ``step``) and ended at
    ``after`` (the inputs of step ``step + 1`` from where the vehicle is now).

    ``collided`` (N,): the step hit something. Without ``q_values`` they are NaN (``n_actions``
    wide)."""
    n = before.distance_m.shape[0]
    steps = np.broadcast_to(np.asarray(step, dtype=np.int64), (n,)).copy()
    coll = np.broadcast_to(np.asarray(collided, dtype=bool), (n,)).copy()
    deviated = after.deviation_m > limits.episode_deviation_m
    goal = goal_reached(path, after, limits.goal_radius_m)
    timeout = steps + 1 >= limits.max_steps
    if q_values is None:
        q = np.full((n, int(n_actions or 0)), np.nan)
    else:
        q = np.asarray(q_values, dtype=np.float64).reshape(n, -1)
    return StepRecord(
        step=steps,
        action=np.broadcast_to(np.asarray(action, dtype=np.int64), (n,)).copy(),
        q_values=q,
        rel_pos_body_m=np.asarray(before.rel_pos_body_m, dtype=np.float64).reshape(n, 3),
        moving_setpoint_world_m=before.setpoint_world_m.reshape(n, 3),
        pos_world_m=np.asarray(pos_world_m, dtype=np.float64).reshape(n, 3),
        yaw_rad=before.yaw_rad.reshape(n),
        end_pos_world_m=np.asarray(end_pos_world_m, dtype=np.float64).reshape(n, 3),
        d_prev_m=before.distance_m.reshape(n),
        d_now_m=after.distance_m.reshape(n),
        progress_m=after.progress_m.reshape(n),
        deviation_m=after.deviation_m.reshape(n),
        deviated=deviated.reshape(n),
        collided=coll,
        reward=reward(before.distance_m, after.distance_m, deviated, coll, reward_params).reshape(n),
        outcome=outcome_codes(coll, deviated, goal, timeout),
        shield_allowed=None if shield_allowed is None else np.asarray(shield_allowed, bool).reshape(n, -1),
        shield_clearance_m=None
        if shield_clearance_m is None
        else np.asarray(shield_clearance_m, dtype=np.float64).reshape(n, -1),
    )
