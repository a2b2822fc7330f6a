"""Gymnasium conventions: the registered id, finite observation bounds, and the VectorEnv view with
Gymnasium 1.x autoreset semantics over the same step as VecQuadNavEnv."""

from __future__ import annotations

import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from gymnasium.vector import AutoresetMode

import sim_harness.env  # noqa: F401  (registers quadnav/QuadNav-v0)
from sim_harness.env import ENV_ID, EnvConfig, QuadNavVectorEnv, VecQuadNavEnv, rel_pos_bound_m
from sim_harness.world import World, load_world, paper_world_path, parse_world

FORWARD = 4  # (1, 0, 0) in DEFAULT_DIRECTIONS


def _world(length_m: float, wall_x_m: float | None = None) -> World:
    """A straight path along x at 2 m height; with ``wall_x_m`` a wall across it there."""
    data: dict = {"name": "line", "path": {"waypoints": [[0, 0, 2], [length_m, 0, 2]]}}
    if wall_x_m is not None:
        data["obstacles"] = [{"type": "box", "center": [wall_x_m, 0, 2], "size": [0.2, 20, 20]}]
    return parse_world(data, "test")


def _wall_world() -> World:
    """Flying forward crashes into the wall within a few steps."""
    return _world(30.0, wall_x_m=3.0)


def test_gym_make_builds_the_registered_env_on_a_paper_world() -> None:
    env = gym.make(ENV_ID, world=3)
    assert env.spec is not None and env.spec.id == "quadnav/QuadNav-v0"
    assert env.unwrapped._worlds[0].name == load_world(paper_world_path(3)).name
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


def test_gym_make_with_the_module_prefix_needs_no_import_first() -> None:
    env = gym.make("sim_harness.env:quadnav/QuadNav-v0", world=[1, 2])
    assert len(env.unwrapped._worlds) == 2


def test_check_env_passes_without_any_warning() -> None:
    """No infinite-bound warning (nor any other) from Gymnasium's checker on the made env."""
    env = gym.make(ENV_ID, world=1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    assert [str(w.message) for w in caught] == []
    space = env.observation_space["rel_pos"]
    assert np.all(np.isfinite(space.low)) and np.all(np.isfinite(space.high))


def test_observations_stay_within_the_bound_through_random_flights_in_every_paper_world() -> None:
    """Random primitives end flights by every reason; every observation, the last included, is in
    the space (the bound holds at the step past the deviation limit too)."""
    worlds = [load_world(paper_world_path(i)) for i in range(1, 11)]
    cfg = EnvConfig(max_steps=60)
    bound = rel_pos_bound_m(worlds, cfg)
    env = VecQuadNavEnv(worlds, 32, seed=5, config=cfg, autoreset=True)
    rng = np.random.default_rng(0)
    env.reset()
    outcomes: set[str] = set()
    for _ in range(120):
        _, rel, _, term, trunc, info = env.step(rng.integers(0, 18, 32))
        assert np.abs(rel).max() <= bound and np.abs(info["final_rel_pos"]).max() <= bound
        outcomes |= {o for o in info["outcome"][term | trunc]}
    assert {"crash", "deviation"} <= outcomes


def test_the_bound_grows_with_the_path_and_the_deviation_limit() -> None:
    short, long = _world(20.0), _world(80.0)
    cfg = EnvConfig()
    assert rel_pos_bound_m([long], cfg) - rel_pos_bound_m([short], cfg) == pytest.approx(60.0)
    assert rel_pos_bound_m([short, long], cfg) == rel_pos_bound_m([long], cfg)


def test_make_vec_gives_a_gymnasium_vector_env_with_batched_spaces() -> None:
    venv = gym.make_vec(ENV_ID, num_envs=3, world=[1, 4])
    assert isinstance(venv, gym.vector.VectorEnv) and isinstance(venv, QuadNavVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    obs, info = venv.reset(seed=1)
    assert obs["depth"].shape == (3, 1, 32, 32) and obs["rel_pos"].shape == (3, 1, 3)
    assert venv.observation_space.contains(obs) and info["_progress_m"].all()
    assert venv.action_space.shape == (3,)


def _forward() -> np.ndarray:
    return np.full(2, FORWARD, dtype=np.int64)


def test_next_step_autoreset_returns_the_last_observation_then_starts_anew_with_reward_zero() -> None:
    venv = QuadNavVectorEnv([_wall_world()], 2, EnvConfig(start_jitter_m=0.0), 0, AutoresetMode.NEXT_STEP)
    venv.reset(seed=0)
    for _ in range(10):
        obs, rew, term, trunc, info = venv.step(_forward())
        if term.any():
            break
    assert term.all() and set(info["outcome"]) == {"crash"} and (rew < 0).all()
    last = obs["rel_pos"].copy()
    obs, rew, term, trunc, info = venv.step(_forward())  # the reset step: action ignored
    assert not term.any() and not trunc.any() and (rew == 0).all()
    assert (info["progress_m"] == 0).all() and not np.array_equal(obs["rel_pos"], last)
    assert venv.unwrapped_vec.steps.tolist() == [0, 0]  # a fresh episode, not stepped yet


def test_same_step_autoreset_puts_the_last_observation_in_final_obs() -> None:
    venv = QuadNavVectorEnv([_wall_world()], 2, EnvConfig(start_jitter_m=0.0), 0, AutoresetMode.SAME_STEP)
    venv.reset(seed=0)
    for _ in range(10):
        obs, _, term, _, info = venv.step(_forward())
        if term.any():
            break
    assert info["_final_obs"].all() and info["final_info"][0]["outcome"] == "crash"
    assert venv.unwrapped_vec.steps.tolist() == [0, 0]
    assert not np.array_equal(info["final_obs"][0]["rel_pos"], obs["rel_pos"][0])


def test_the_vector_view_steps_exactly_as_vec_quadnav_env() -> None:
    """Same seed and actions: rewards and observations equal VecQuadNavEnv's while no env ended."""
    worlds = [load_world(paper_world_path(i)) for i in (1, 2)]
    venv = QuadNavVectorEnv(worlds, 4, seed=9)
    ref = VecQuadNavEnv(worlds, 4, seed=9, autoreset=False)
    obs, _ = venv.reset()
    depth, rel = ref.reset()
    rng = np.random.default_rng(3)
    for _ in range(5):
        a = rng.integers(0, 18, 4)
        obs, rew, term, trunc, _ = venv.step(a)
        depth, rel, rew_ref, term_ref, _, _ = ref.step(a)
        assert np.array_equal(obs["depth"], depth) and np.array_equal(obs["rel_pos"], rel)
        assert np.array_equal(rew, rew_ref) and np.array_equal(term, term_ref)
        if (term | trunc).any():
            break
