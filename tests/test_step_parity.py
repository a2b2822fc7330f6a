"""What is trained is what flies: the training env and the flight daemon's step, fed the same poses,
frames and model, choose the same primitives and write equal step records over whole flights."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from quadnav_onboard import step
from quadnav_onboard.daemon.decide import Decider, Motion
from quadnav_onboard.daemon.stepper import MissionStepper
from quadnav_onboard.policy import Policy, masked_argmax
from quadnav_onboard.sources.base import DepthFrame
from sim_harness.env import VecQuadNavEnv, at_primitive_scale
from sim_harness.render import render_input_frames_mm
from sim_harness.rl.evaluate import env_config_for_policy
from sim_harness.world import load_world, paper_world_path


@pytest.fixture(scope="module")
def policy() -> Policy:
    return Policy.from_path()


def _fly_both(policy: Policy, world_id: int, scale_m: float, seed: int) -> int:
    """One whole flight in the env; at every step the daemon's stepper gets the env's pose and the
    sim camera's frame and must agree. Returns the steps flown."""
    cfg, worlds = at_primitive_scale(env_config_for_policy(policy), [load_world(paper_world_path(world_id))],
                                     scale_m)
    world = worlds[0]
    env = VecQuadNavEnv([world], 1, seed=seed, config=cfg, autoreset=False)
    depth, rel = env.reset()
    prims = cfg.primitives.build()
    decider = Decider(policy, cfg.preprocess, prims)
    limits = step.EpisodeLimits(cfg.goal_radius_m, cfg.reward.max_deviation_m, cfg.max_steps)
    stepper = MissionStepper(world.path, prims, decider, limits, cfg.reward)
    start, start_vel = env.pos_m[0].copy(), np.zeros(3)
    k = 0
    while not env.done[0]:
        pos, vel = env.pos_m[0].copy(), env.vel_m_s[0].copy()
        inputs = stepper.inputs(k, pos)
        frame = DepthFrame(render_input_frames_mm(world, pos[None], [inputs.yaw_rad])[0], 0.0, k)
        motion = Motion(pos, vel, start, start_vel, inputs.yaw_rad)
        if k % 2:  # the two ways a flight decides: prepared ahead (with the verdict) or at the boundary
            prepared = decider.prepare(frame, decider.snapshot(), motion, decider.memory)
        else:
            prepared = decider.prepare(frame, decider.snapshot())
        pending = stepper.decide(k, inputs, prepared, "prepared", motion, float(k))

        q_env = policy.q_values_batch(depth, rel)
        action = int(masked_argmax(q_env, env.allowed)[0])
        assert pending.decision.action == action, f"step {k}: daemon {pending.decision.action}, env {action}"
        np.testing.assert_allclose(pending.decision.q, q_env[0], rtol=0, atol=1e-5)
        np.testing.assert_array_equal(pending.decision.allowed, env.allowed[0])
        np.testing.assert_array_equal(pending.decision.depth_input, env.depth[0, -1])

        depth, rel, *_ = env.step(np.array([action]))
        flown = env.last_step
        assert flown is not None
        daemon = stepper.finish(pending, env.pos_m[0], collided=bool(flown.collided[0]))
        for f in dataclasses.fields(step.StepRecord):
            if f.name == "q_values":  # the env does not see the agent's Q-values
                continue
            a, b = getattr(daemon, f.name), getattr(flown, f.name)
            assert (a is None) == (b is None), f.name
            if a is not None:
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-9, err_msg=f"step {k}: {f.name}")
        start, start_vel = pending.primitive.end_world_m, pending.primitive.end_vel_world_m_s
        np.testing.assert_allclose(start, env.cmd_pos_m[0], rtol=0, atol=1e-9)
        k += 1
    return k


@pytest.mark.parametrize(("world_id", "scale_m", "seed"), [(4, 1.0, 0), (8, 1.0, 1), (10, 0.5, 2)])
def test_env_and_daemon_fly_the_same_flight(policy: Policy, world_id: int, scale_m: float, seed: int) -> None:
    """Same actions, Q-values, filter verdicts, network inputs and step records at every step, to
    the flight's end (goal, crash, deviation or step limit)."""
    steps = _fly_both(policy, world_id, scale_m, seed)
    assert steps >= 20  # a whole flight, not one that ended at the start


def test_a_drifting_side_fails_the_parity_check(policy: Policy, monkeypatch: pytest.MonkeyPatch) -> None:
    """The check is not vacuous: a daemon whose reward reads one constant differently is caught."""
    original = step.finish_step

    def drifted(*args, **kwargs):
        if kwargs.get("q_values") is not None:  # the daemon's side only
            params = kwargs["reward_params"]
            kwargs["reward_params"] = dataclasses.replace(params, r_upper=params.r_upper + 0.5)
        return original(*args, **kwargs)

    monkeypatch.setattr(step, "finish_step", drifted)
    with pytest.raises(AssertionError, match="reward"):
        _fly_both(policy, 4, 1.0, 0)
