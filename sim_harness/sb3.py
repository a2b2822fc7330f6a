"""Stable-Baselines3 on the navigation env (the ``sb3`` extra: ``pip install "quadnav[sb3]"``).

- :class:`PaperLanes`: an SB3 features extractor made of the paper's depth and position lanes
  (:class:`quadnav_onboard.network.DQN`); with ``net_arch=[64, 32]`` SB3's Q-network is the
  paper's network, layer for layer (:func:`paper_policy_kwargs`). SB3's own ``NatureCNN`` refuses
  32x32 depth images (its kernels need at least 36x36).
- :class:`QuadNavSB3VecEnv`: an SB3 ``VecEnv`` that steps N envs in one batch
  (:class:`sim_harness.env.VecQuadNavEnv` with its same-step autoreset, which is SB3's convention:
  ``terminal_observation`` and ``TimeLimit.truncated`` in the infos, ``episode`` as SB3's
  ``Monitor`` writes it).
- :func:`train_dqn`: SB3's DQN on the paper's training worlds with both, one torch and one numba
  thread; :func:`greedy_fn` flies the result in :func:`sim_harness.rl.evaluate.evaluate`.

``python -m sim_harness.sb3 --timesteps 20000 --out sb3_dqn.zip`` trains, saves and evaluates
(docs/training.md, "Stable-Baselines3").
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from typing import Any

import gymnasium as gym
import numpy as np
import structlog
import torch
from numpy.typing import NDArray
from stable_baselines3 import DQN as SB3DQN
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.policy import masked_argmax
from sim_harness.env import EnvConfig, VecQuadNavEnv, observation_space
from sim_harness.rl.evaluate import GreedyFn
from sim_harness.rl.threads import limit_threads
from sim_harness.world import World, load_world, paper_world_path

__all__ = ["PaperLanes", "QuadNavSB3VecEnv", "greedy_fn", "paper_policy_kwargs", "train_dqn"]

log = structlog.get_logger(__name__)

FEATURES_DIM = 80
"""Depth lane (64) + position lane (16): what the paper's trunk takes."""


class PaperLanes(BaseFeaturesExtractor):
    """The paper's two input lanes as SB3 features: ``obs["depth"]`` (B, k_d, 32, 32) in [0, 1] ->
    64, ``obs["rel_pos"]`` (B, k_p, 3) m, heading frame -> 16 (x/y/z sub-lanes, then merged);
    concatenated (B, 80). The lanes are :class:`quadnav_onboard.network.DQN`'s own modules."""

    def __init__(self, observation_space: gym.spaces.Dict) -> None:
        super().__init__(observation_space, features_dim=FEATURES_DIM)
        kd = observation_space["depth"].shape[0]
        kp = observation_space["rel_pos"].shape[0]
        net = DQN(NetworkConfig(depth_history=kd, position_history=kp))
        self.depth_lane = net.depth_lane
        self.pos_x, self.pos_y, self.pos_z, self.pos_merge = net.pos_x, net.pos_y, net.pos_z, net.pos_merge

    def forward(self, observations: dict[str, torch.Tensor]) -> torch.Tensor:
        rel = observations["rel_pos"]
        p = torch.cat([self.pos_x(rel[..., 0]), self.pos_y(rel[..., 1]), self.pos_z(rel[..., 2])], dim=-1)
        return torch.cat([self.depth_lane(observations["depth"]), self.pos_merge(p)], dim=-1)


def paper_policy_kwargs() -> dict[str, Any]:
    """``policy_kwargs`` of SB3's ``MultiInputPolicy`` giving the paper's network: the lanes, then
    80 -> 64 -> 32 -> n_actions with ReLU (73,946 parameters for one frame and one position)."""
    return {
        "features_extractor_class": PaperLanes,
        "net_arch": [64, 32],
        "activation_fn": nn.ReLU,
        "normalize_images": False,
    }


class QuadNavSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` over :class:`VecQuadNavEnv` (``n_envs`` episodes stepped in one batch)."""

    def __init__(
        self, worlds: Sequence[World], n_envs: int, seed: int = 0, config: EnvConfig = EnvConfig()
    ) -> None:
        self.vec = VecQuadNavEnv(list(worlds), n_envs, seed, config, autoreset=True)
        self._actions = np.zeros(n_envs, dtype=np.int64)
        actions = gym.spaces.Discrete(self.vec.prims.n_actions)
        super().__init__(n_envs, observation_space(self.vec.worlds, config), actions)

    def _obs(self, depth: NDArray, rel: NDArray) -> dict[str, NDArray[np.float32]]:
        return {"depth": depth.copy(), "rel_pos": rel.copy()}

    def reset(self) -> dict[str, NDArray[np.float32]]:
        if self._seeds[0] is not None:
            self.vec.rng = np.random.default_rng(self._seeds[0])
        self._reset_seeds()
        return self._obs(*self.vec.reset())

    def step_async(self, actions: NDArray) -> None:
        self._actions = np.asarray(actions, dtype=np.int64)

    def step_wait(self) -> tuple[dict[str, NDArray[np.float32]], NDArray, NDArray, list[dict[str, Any]]]:
        depth, rel, rew, term, trunc, info = self.vec.step(self._actions)
        done = term | trunc
        infos: list[dict[str, Any]] = [{} for _ in range(self.num_envs)]
        for i in np.flatnonzero(done):
            infos[i] = {
                "terminal_observation": {
                    "depth": info["final_depth"][i],
                    "rel_pos": info["final_rel_pos"][i],
                },
                "TimeLimit.truncated": bool(trunc[i] and not term[i]),
                "episode": {"r": float(info["episode_return"][i]), "l": int(info["steps"][i]), "t": 0.0},
                "outcome": info["outcome"][i],
            }
        return self._obs(depth, rel), rew.astype(np.float32), done, infos

    def close(self) -> None:
        pass

    def get_attr(self, attr_name: str, indices: Any = None) -> list[Any]:
        value = None if attr_name == "render_mode" else getattr(self.vec, attr_name)
        return [value] * len(self._get_indices(indices))

    def set_attr(self, attr_name: str, value: Any, indices: Any = None) -> None:
        setattr(self.vec, attr_name, value)

    def env_method(self, method_name: str, *method_args: Any, indices: Any = None, **kwargs: Any) -> list:
        raise NotImplementedError(f"{type(self).__name__} has no per-env {method_name}()")

    def env_is_wrapped(self, wrapper_class: type, indices: Any = None) -> list[bool]:
        return [False] * len(self._get_indices(indices))


def train_dqn(
    worlds: Sequence[World] | None = None,
    *,
    timesteps: int,
    n_envs: int = 16,
    seed: int = 0,
    config: EnvConfig = EnvConfig(),
    **dqn_kwargs: Any,
) -> SB3DQN:
    """SB3's DQN with the paper's network on ``worlds`` (default: paper worlds 1-7) for
    ``timesteps`` env steps (all envs counted). ``dqn_kwargs`` go to SB3's ``DQN`` over these
    defaults: buffer 50 000, 1 000 steps before learning, batch 64, γ 0.99, ε from 1 to 0.1 over
    the first half, a target copy every 250 updates, one update per vectorised step."""
    limit_threads(1, 1)
    worlds = list(worlds) if worlds is not None else [load_world(paper_world_path(i)) for i in range(1, 8)]
    venv = QuadNavSB3VecEnv(worlds, n_envs, seed, config)
    kwargs: dict[str, Any] = {
        "buffer_size": 50_000,
        "learning_starts": 1_000,
        "batch_size": 64,
        "gamma": 0.99,
        "exploration_fraction": 0.5,
        "exploration_final_eps": 0.1,
        "target_update_interval": 250,
        "train_freq": 1,
        "gradient_steps": 1,
        "policy_kwargs": paper_policy_kwargs(),
        "seed": seed,
        "device": "cpu",
        "verbose": 0,
        **dqn_kwargs,
    }
    model = SB3DQN("MultiInputPolicy", venv, **kwargs)
    if not kwargs.get("tensorboard_log"):
        # SB3's default logger makes an empty tempdir/SB3-<time> folder on every learn(), even
        # with nothing to write; a logger with no outputs makes none.
        model.set_logger(Logger(folder=None, output_formats=[]))
    log.info("sb3_dqn", timesteps=timesteps, n_envs=n_envs, seed=seed)
    model.learn(total_timesteps=timesteps, progress_bar=False)
    return model


def greedy_fn(model: SB3DQN) -> GreedyFn:
    """The SB3 model as a batched greedy policy for :func:`sim_harness.rl.evaluate.evaluate`."""
    q_net = model.q_net

    def act(depth: NDArray[np.float32], rel: NDArray[np.float32], allowed: NDArray[np.bool_]) -> NDArray:
        with torch.no_grad():
            q = q_net({"depth": torch.as_tensor(depth), "rel_pos": torch.as_tensor(rel)}).numpy()
        return masked_argmax(q, allowed)

    return act


def main(argv: list[str] | None = None) -> int:
    from sim_harness.rl.evaluate import evaluate, summarize

    p = argparse.ArgumentParser(prog="python -m sim_harness.sb3", description=__doc__.split("\n")[0])
    p.add_argument("--timesteps", type=int, default=20_000, help="env steps of training (all envs)")
    p.add_argument("--n-envs", type=int, default=16, help="envs stepped together")
    p.add_argument("--seed", type=int, default=0, help="seed of the env, SB3 and torch")
    p.add_argument("--out", default="sb3_dqn.zip", help="where SB3 saves the model")
    p.add_argument("--trials", type=int, default=5, help="evaluation trials per paper world")
    a = p.parse_args(argv)
    model = train_dqn(timesteps=a.timesteps, n_envs=a.n_envs, seed=a.seed)
    model.save(a.out)
    worlds = [load_world(paper_world_path(i)) for i in range(1, 11)]
    rows = evaluate(greedy_fn(model), worlds, a.trials, seed=1000)
    s = summarize(rows)
    print(f"saved {a.out}; goal {s['success_rate']:.0%}, collision-free {s['collision_free_rate']:.0%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
