"""The RL environment: Gymnasium compliance, reproducibility, step semantics and episode ends."""

from __future__ import annotations

import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

from sim_harness.env import EnvConfig, QuadNavEnv, VecQuadNavEnv
from sim_harness.world import load_world, paper_world_path, parse_world

FORWARD = 4  # (1, 0, 0) in DEFAULT_DIRECTIONS
HOVER = 13  # (0, 0, 0)


def _free_world(length_m: float = 20.0):
    return parse_world(
        {"name": "free", "path": {"waypoints": [[0, 0, 2], [length_m, 0, 2]]}, "bounds": {"floor_z": 0.0}},
        "test",
    )


def _wall_world():
    return parse_world(
        {
            "name": "wall",
            "path": {"waypoints": [[0, 0, 2], [30, 0, 2]]},
            "obstacles": [{"type": "box", "center": [5.0, 0, 2], "size": [0.2, 20, 20]}],
        },
        "test",
    )


def test_check_env_passes() -> None:
    env = QuadNavEnv([load_world(paper_world_path(4))], EnvConfig(depth_history=2, position_history=3))
    check_env(env, skip_render_check=True)


def test_seeded_episode_is_reproducible_bit_for_bit() -> None:
    worlds = [load_world(paper_world_path(i)) for i in (1, 4, 6)]

    def rollout() -> list[tuple]:
        env = QuadNavEnv(worlds)
        obs, info = env.reset(seed=123)
        actions = np.random.default_rng(7).integers(0, 18, size=40)
        out = [(obs["depth"].tobytes(), obs["rel_pos"].tobytes(), info["world_index"])]
        for a in actions:
            obs, r, term, trunc, info = env.step(int(a))
            out.append((obs["depth"].tobytes(), obs["rel_pos"].tobytes(), r, info["outcome"]))
            if term or trunc:
                break
        return out

    first, second = rollout(), rollout()
    assert first == second
    assert len(first) > 2


def test_different_seeds_give_different_starts() -> None:
    env = QuadNavEnv([_free_world()], EnvConfig(start_jitter_m=0.5))
    a = env.reset(seed=1)[0]["rel_pos"]
    b = env.reset(seed=2)[0]["rel_pos"]
    assert not np.array_equal(a, b)


def test_flying_forward_in_a_free_world_reaches_the_goal_with_positive_reward() -> None:
    env = VecQuadNavEnv([_free_world(20.0)], 3, seed=0, config=EnvConfig(start_jitter_m=0.0), autoreset=False)
    env.reset()
    total = np.zeros(3)
    outcome = None
    for _ in range(40):
        _, _, r, term, _trunc, info = env.step(np.full(3, FORWARD))
        total += r
        if term.any():
            outcome = info["outcome"]
            break
    assert list(outcome) == ["goal"] * 3
    assert np.all(info["progress_m"] >= 19.0 - 1e-6)
    assert np.all(total > 0)
    # the moving setpoint advances 1 m per 1-s step
    assert np.all(info["time_s"] == info["steps"] * 1.0)


def test_relative_position_is_setpoint_minus_quad_in_heading_frame() -> None:
    env = VecQuadNavEnv([_free_world()], 1, seed=0, config=EnvConfig(start_jitter_m=0.0), autoreset=False)
    _, rel = env.reset()
    np.testing.assert_allclose(rel[0, -1], [0.0, 0.0, 0.0], atol=1e-6)
    for _ in range(3):
        _, rel, *_ = env.step(np.array([HOVER]))
    # hovering at the start while the setpoint slides 3 m ahead along +x
    np.testing.assert_allclose(rel[0, -1], [3.0, 0.0, 0.0], atol=1e-3)


def test_wall_across_the_path_ends_in_a_crash_with_the_collision_penalty() -> None:
    env = VecQuadNavEnv([_wall_world()], 2, seed=0, config=EnvConfig(start_jitter_m=0.0), autoreset=False)
    env.reset()
    for _ in range(10):
        _, _, r, term, _, info = env.step(np.full(2, FORWARD))
        if term.any():
            break
    assert list(info["outcome"]) == ["crash", "crash"]
    assert np.all(r == -1.0)
    assert np.all(info["progress_m"] < 5.0)


def test_deviation_past_the_limit_ends_the_episode() -> None:
    left = 16  # (0, 1, 0): sideways only
    env = VecQuadNavEnv([_free_world(60.0)], 1, seed=0, config=EnvConfig(start_jitter_m=0.0), autoreset=False)
    env.reset()
    for _ in range(10):
        _, _, r, term, _, info = env.step(np.array([left]))
        if term[0]:
            break
    assert info["outcome"][0] == "deviation"
    assert r[0] == -0.5


def test_step_limit_truncates() -> None:
    env = VecQuadNavEnv([_free_world(60.0)], 1, seed=0, config=EnvConfig(max_steps=5), autoreset=False)
    env.reset()
    for _ in range(5):
        _, _, _, term, trunc, info = env.step(np.array([HOVER]))
    assert trunc[0] and not term[0]
    assert info["outcome"][0] == "timeout"
    assert env.done[0]


def test_autoreset_starts_a_new_episode_and_reports_the_final_observation() -> None:
    env = VecQuadNavEnv([_wall_world()], 1, seed=0, config=EnvConfig(start_jitter_m=0.0))
    env.reset()
    for _ in range(10):
        _depth, rel, _, term, _, info = env.step(np.array([FORWARD]))
        if term[0]:
            break
    assert term[0]
    assert env.steps[0] == 0 and not env.done[0]
    np.testing.assert_allclose(rel[0, -1], [0.0, 0.0, 0.0], atol=1e-6)  # fresh start at the setpoint
    assert info["final_rel_pos"][0, -1, 0] != pytest.approx(0.0, abs=1e-3)


def test_history_shifts_oldest_first() -> None:
    cfg = EnvConfig(start_jitter_m=0.0, position_history=3)
    env = VecQuadNavEnv([_free_world(60.0)], 1, seed=0, config=cfg, autoreset=False)
    env.reset()
    for _ in range(2):
        _, rel, *_ = env.step(np.array([HOVER]))
    np.testing.assert_allclose(rel[0, :, 0], [0.0, 1.0, 2.0], atol=1e-3)


def test_worlds_are_sampled_from_the_list() -> None:
    worlds = [_free_world(), _wall_world()]
    env = VecQuadNavEnv(worlds, 64, seed=3)
    env.reset()
    assert set(env.world_idx.tolist()) == {0, 1}


def test_the_training_env_remembers_each_surface_where_its_pixel_saw_it() -> None:
    """The env's filter memory after reset in lab02 (boxes at 45 degrees) holds the nearest-surface
    view placed by ``near_at``, as the daemon's decider places it; on the cells' centre rays the
    points would lie elsewhere (this fails if the env drops ``near_at``)."""
    from quadnav_onboard.shield import PointMemory, ShieldConfig
    from quadnav_onboard.step import step_inputs
    from sim_harness.render import render_inputs
    from sim_harness.world import resolve_world_arg

    world = load_world(resolve_world_arg("lab02"))
    shield = ShieldConfig(enabled=True)
    env = VecQuadNavEnv([world], 3, seed=0, config=EnvConfig(shield=shield), autoreset=False)
    env.reset()
    assert env.memory is not None
    yaw = step_inputs(world.path, env.steps, env.prims.duration_s, env.pos_m).yaw_rad
    view = render_inputs(world, env.pos_m, yaw, env.config.preprocess, nearest=True)
    placed, centred = PointMemory(3, shield), PointMemory(3, shield)
    placed.add(np.arange(3), view.near, env.pos_m, yaw, view.near_at)
    centred.add(np.arange(3), view.near, env.pos_m, yaw)
    np.testing.assert_allclose(env.memory.points, placed.points, atol=1e-5)
    seen = np.isfinite(placed.points[..., 0])
    assert seen.any() and np.abs(placed.points[seen] - centred.points[seen]).max() > 0.01
