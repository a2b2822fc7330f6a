"""Random starts along the path (a training aid, off by default)."""

import numpy as np

from sim_harness.collision import clearance_m
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.world import load_world, paper_world_path

WORLDS = [load_world(paper_world_path(i)) for i in (4, 6)]


def test_off_by_default_every_episode_starts_at_the_path_start():
    env = VecQuadNavEnv(WORLDS, 32, seed=0)
    env.reset()
    assert (env.steps == 0).all()
    assert (np.abs(env.pos_m[:, 0]) <= EnvConfig().start_jitter_m + 1e-9).all()


def test_random_starts_are_free_and_the_setpoint_is_level_with_them():
    """Mid-path starts keep the clearance asked for, and the step counter (hence the moving
    setpoint) matches the distance already covered at the path's speed."""
    cfg = EnvConfig(random_start_prob=1.0)
    env = VecQuadNavEnv(WORLDS, 64, seed=3, config=cfg)
    env.reset()
    moved = env.steps > 0
    assert moved.mean() > 0.8  # a few may fall back to the start after failed draws
    for i in np.flatnonzero(moved):
        world = WORLDS[env.world_idx[i]]
        assert clearance_m(world, env.pos_m[i]) > cfg.quad.radius_m + cfg.random_start_clearance_m
        arc = world.path.progress_m(env.pos_m[i])
        assert abs(env.steps[i] - arc / world.path.speed_m_s) <= 1.0 + cfg.start_jitter_m


def test_random_starts_are_seeded():
    a = VecQuadNavEnv(WORLDS, 16, seed=7, config=EnvConfig(random_start_prob=0.5))
    b = VecQuadNavEnv(WORLDS, 16, seed=7, config=EnvConfig(random_start_prob=0.5))
    np.testing.assert_array_equal(a.reset()[1], b.reset()[1])
    np.testing.assert_array_equal(a.steps, b.steps)
