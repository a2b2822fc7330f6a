"""DAgger in one lab: random box layouts of its room, flown under its flight config.

The training config's ``lab_*`` keys (:class:`~sim_harness.rl.config.TrainConfig`) name a world
file of the room and the flight config flown there; :func:`lab_task` turns them into one
:class:`~sim_harness.rl.imitation.DaggerTask`: the layouts (:mod:`sim_harness.lab_layouts`, each
with a route that keeps the filter's margins), the env as ``quadnav-sim eval --flight-config``
flies a world (the flight's primitives, step limit, goal radius, deviation limit; the filter
knowing the room, the geofence and the deviation band; D435-like depth noise), and a teacher that
plans within the flight's deviation limit to its goal radius.
"""

from __future__ import annotations

import dataclasses
import functools
from pathlib import Path

from quadnav_onboard.config import ConfigError
from sim_harness.env import EnvConfig
from sim_harness.lab_layouts import lab_layouts, route_admits
from sim_harness.noise import DepthNoise
from sim_harness.rl.config import TrainConfig
from sim_harness.rl.evaluate import FlightLimits, NoisyDepthEnv, flight_setup_for, known_room
from sim_harness.rl.imitation import DaggerTask, Labeller
from sim_harness.rl.teacher import Teacher, teacher_config
from sim_harness.world import World, load_world, resolve_world_arg

__all__ = ["LabSetup", "flight_layouts", "lab_setup", "lab_task"]


@dataclasses.dataclass(frozen=True)
class LabSetup:
    """A lab's room under its flight config: the env every layout is flown in, and the room."""

    config: EnvConfig
    room: World
    limits: FlightLimits


def lab_setup(cfg: TrainConfig, trained: EnvConfig) -> LabSetup:
    """Load ``cfg.lab_world`` and ``cfg.lab_flight_config`` (errors name the file and key) and set
    up the env a network trained in ``trained`` flies that flight in."""
    from quadnav_onboard.daemon.config import check_mission_path, load_flight_config

    flight = load_flight_config(cfg.lab_flight_config, require_waypoints=False)
    try:
        room = load_world(resolve_world_arg(cfg.lab_world))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"key 'lab_world': bad value {cfg.lab_world!r}: {exc}") from exc
    env_cfg, (room,), limits = flight_setup_for(trained, flight, [room])
    check_mission_path(flight, room.path, cfg.lab_flight_config, f"lab_world {Path(cfg.lab_world).name}")
    shield = known_room(env_cfg.shield, room, limits)  # every layout shares the room and the path
    return LabSetup(dataclasses.replace(env_cfg, shield=shield), room, limits)


def flight_layouts(room: World, env_cfg: EnvConfig, limits: FlightLimits, n: int, seed: int) -> list[World]:
    """``n`` random layouts of ``room`` (reproducible from ``seed``) for the flight ``env_cfg`` and
    ``limits`` (:func:`~sim_harness.rl.evaluate.flight_setup_for`), each with a sequence of its
    primitives that keeps the margins of its filter knowing the room to the goal."""
    shield = known_room(env_cfg.shield, room, limits)
    admits = route_admits(
        lambda _w: shield, env_cfg.primitives.build(), env_cfg.goal_radius_m, env_cfg.max_steps,
        (limits.altitude_floor_m, limits.altitude_ceiling_m), env_cfg.reward.max_deviation_m,
    )
    return lab_layouts(room, n, seed, admits)


def lab_task(cfg: TrainConfig, lab: LabSetup, teacher: Labeller | None = None) -> DaggerTask:
    """``cfg.lab_layouts`` layouts of ``lab``'s room and the DAgger task that flies them;
    ``teacher``: the labeller (default: the privileged teacher within the flight's limits)."""
    env_cfg = lab.config
    shield = env_cfg.shield
    max_dev = env_cfg.reward.max_deviation_m  # the episode's stop: the flight's deviation limit
    layouts = flight_layouts(lab.room, env_cfg, lab.limits, cfg.lab_layouts, cfg.lab_layout_seed)
    if teacher is None:
        teacher = Teacher(teacher_config(
            cfg, grid_m=min(cfg.teacher_grid_m, 0.1),
            max_deviation_m=max(max_dev - shield.band_margin_m, 0.1), goal_radius_m=env_cfg.goal_radius_m,
        ))
    make_env = functools.partial(NoisyDepthEnv, noise=DepthNoise(), noise_seed=cfg.seed + 7919)
    return DaggerTask(env_cfg, layouts, teacher, make_env, noise=cfg.lab_dagger_noise)
