"""Greedy evaluation: the paper's table (per world and trial) and its summary rates.

Each world runs its ``trials`` episodes together in one :class:`VecQuadNavEnv` (no auto-reset);
trials differ by their seeded start jitter. Rows hold the paper's columns (navigation distance m,
navigation time s, crash Y/N, total reward) plus the outcome. ``summarize`` counts success (goal),
collision-free flights and success among the collision-free ones.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.policy import Policy, masked_argmax
from quadnav_onboard.shield import ShieldConfig, shield_config_from_meta
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.world import World

__all__ = [
    "EvalRow",
    "GreedyFn",
    "env_config_for_policy",
    "evaluate",
    "format_table",
    "override_shield",
    "policy_greedy_fn",
    "scores",
    "summarize",
]

GreedyFn = Callable[[NDArray[np.float32], NDArray[np.float32], NDArray[np.bool_]], NDArray[np.int64]]
"""Batched policy: depth (B, k_d, 32, 32), rel (B, k_p, 3), allowed (B, n_actions) -> actions (B,).
``allowed`` is the shield's verdict (all True when the shield is off)."""


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
    """goal | crash | deviation | timeout."""

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


def policy_greedy_fn(policy: Policy) -> GreedyFn:
    return lambda depth, rel, allowed: masked_argmax(policy.q_values_batch(depth, rel), allowed)


def evaluate(
    act: GreedyFn,
    worlds: Sequence[World],
    trials: int,
    seed: int,
    env_config: EnvConfig = EnvConfig(),
    on_world_done: Callable[[World], None] | None = None,
) -> list[EvalRow]:
    """Fly ``trials`` greedy episodes in each world; rows in world order, then trial order."""
    rows: list[EvalRow] = []
    for w_i, world in enumerate(worlds):
        env = VecQuadNavEnv([world], trials, seed=seed * 1009 + w_i, config=env_config, autoreset=False)
        depth, rel = env.reset()
        outcome = np.full(trials, None, dtype=object)
        progress = np.zeros(trials)
        while not env.done.all():
            depth, rel, _, term, trunc, info = env.step(act(depth, rel, env.allowed))
            ended = term | trunc
            outcome[ended] = info["outcome"][ended]
            progress[ended] = info["progress_m"][ended]
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
