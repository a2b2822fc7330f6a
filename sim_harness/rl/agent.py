"""The DQN learner: online and target Q-networks, Huber loss, Adam, ε-greedy acting.

Options beyond the paper (all off by default): Double DQN targets, a dueling head (in the network
config), n-step returns (the buffer supplies ``n``; the target bootstraps with ``γ**n``), and
importance-weighted losses for prioritised replay (``Batch.weight``; the update keeps each sample's
|TD error| in ``last_td_abs`` for the buffer's new priorities).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.policy import masked_argmax
from sim_harness.rl.replay import Batch

__all__ = ["AgentConfig", "DQNAgent", "random_allowed"]


def random_allowed(allowed: NDArray[np.bool_], rng: np.random.Generator) -> NDArray[np.int64]:
    """One action per row of ``allowed`` (B, n_actions), uniform over the row's allowed ones (the
    filter allows at least one in every row, ``quadnav_onboard.shield.allowed_actions``)."""
    return np.argmax(rng.random(allowed.shape) * allowed, axis=1).astype(np.int64)


@dataclass(frozen=True)
class AgentConfig:
    """Learner settings."""

    learning_rate: float = 1e-3
    """Adam step size (PyTorch's default, 1e-3; the paper states none)."""
    double_dqn: bool = False
    """Double DQN targets: the online net picks a', the target net evaluates it."""
    target_update_interval: int = 250
    """Gradient updates between hard copies of the online net into the target net."""
    max_grad_norm: float = 10.0
    """Gradient norm clip (0 = off)."""


class DQNAgent:
    """Online/target networks and their optimiser; ``torch`` seeded by the caller."""

    def __init__(
        self, network: NetworkConfig, config: AgentConfig = AgentConfig(), device: str = "cpu"
    ) -> None:
        self.config = config
        self.device = torch.device(device)
        self.q = DQN(network).to(self.device)
        self.target = DQN(network).to(self.device)
        self.target.load_state_dict(self.q.state_dict())
        self.target.eval()
        self.optimizer = torch.optim.Adam(self.q.parameters(), lr=config.learning_rate)
        self.n_updates = 0
        self.last_td_abs: NDArray[np.float32] = np.zeros(0, dtype=np.float32)
        """|target - Q(s, a)| of each sample of the last update (prioritised replay's priorities)."""

    def greedy(
        self, depth: NDArray[np.float32], rel: NDArray[np.float32], allowed: NDArray[np.bool_] | None = None,
        scale_m: float | None = None,
    ) -> NDArray[np.int64]:
        """Arg-max actions (B,) for a batch: depth (B, k_d, 32, 32), rel (B, k_p, 3); over the
        ``allowed`` actions (B, n_actions) only, when given (the shield's verdict). ``scale_m``:
        the primitive scale the batch flies at, for a network that reads it (ignored otherwise)."""
        with torch.inference_mode():
            q = self.q(self._t(depth), self._t(rel), self.scale_rows(scale_m, depth.shape[0])).cpu().numpy()
        return masked_argmax(q, allowed)

    def scale_rows(self, scale_m: float | NDArray | None, n: int) -> torch.Tensor | None:
        """``scale_m`` (one scale, or one per row) as the network's scale input (n,), or None for a
        network that does not read it, or when none is given (the network then says what it is
        missing, or which rows were never told their scale)."""
        if scale_m is None or not self.q.config.scale_input:
            return None
        return self._t(np.broadcast_to(np.asarray(scale_m, dtype=np.float32), (n,)).copy())

    def _t(self, a: NDArray) -> torch.Tensor:
        return torch.as_tensor(a).to(self.device, non_blocking=True)

    def act(
        self,
        depth: NDArray[np.float32],
        rel: NDArray[np.float32],
        epsilon: NDArray | float,
        rng: np.random.Generator,
        allowed: NDArray[np.bool_] | None = None,
        scale_m: float | None = None,
    ) -> NDArray[np.int64]:
        """ε-greedy actions (B,); ``epsilon`` scalar or per row; randomness from ``rng``. With
        ``allowed`` (B, n_actions) both the greedy and the random choice keep to allowed actions."""
        n = depth.shape[0]
        actions = self.greedy(depth, rel, allowed, scale_m)
        explore = rng.random(n) < np.broadcast_to(np.asarray(epsilon, dtype=np.float64), (n,))
        if allowed is None:
            random_actions = rng.integers(0, self.q.config.n_actions, size=n)
        else:
            random_actions = random_allowed(allowed, rng)
        return np.where(explore, random_actions, actions).astype(np.int64)

    def td_target(self, batch: Batch, gamma: float) -> torch.Tensor:
        """Bootstrapped targets (B,): ``r + γ^n (1 - done) max_a' Q_target(s', a')``, the max over
        the actions the shield allowed in s' (Double DQN: the online net picks a'). The shield always
        allows at least one action (``allowed_actions``), so the max is finite."""
        next_depth, next_rel = self._t(batch.next_depth), self._t(batch.next_rel)
        reward, done = self._t(batch.reward), self._t(batch.done)
        discount = self._t(np.power(gamma, batch.n, dtype=np.float32))
        with torch.no_grad():
            q_next_target = self.target(next_depth, next_rel)
            mask = None if batch.next_allowed is None else self._t(batch.next_allowed)
            if mask is not None:
                q_next_target = q_next_target.masked_fill(~mask, -torch.inf)
            if self.config.double_dqn:
                q_next_online = self.q(next_depth, next_rel)
                if mask is not None:
                    q_next_online = q_next_online.masked_fill(~mask, -torch.inf)
                a_next = q_next_online.argmax(dim=1, keepdim=True)
                v_next = q_next_target.gather(1, a_next).squeeze(1)
            else:
                v_next = q_next_target.max(dim=1).values
            return reward + discount * (1.0 - done) * v_next

    def update(self, batch: Batch, gamma: float) -> float:
        """One gradient step of the Huber TD loss (weighted by ``batch.weight`` when given);
        returns the loss value."""
        depth, rel = self._t(batch.depth), self._t(batch.rel)
        action = self._t(batch.action)
        target = self.td_target(batch, gamma)
        q_sa = self.q(depth, rel).gather(1, action[:, None]).squeeze(1)
        if batch.weight is None:
            loss = F.smooth_l1_loss(q_sa, target)
        else:
            per_sample = F.smooth_l1_loss(q_sa, target, reduction="none")
            loss = (self._t(batch.weight) * per_sample).mean()
        self.last_td_abs = (target - q_sa).detach().abs().cpu().numpy()
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.config.max_grad_norm > 0:
            torch.nn.utils.clip_grad_norm_(self.q.parameters(), self.config.max_grad_norm)
        self.optimizer.step()
        self.n_updates += 1
        if self.n_updates % self.config.target_update_interval == 0:
            self.target.load_state_dict(self.q.state_dict())
        return float(loss.detach().cpu())

    def cpu_model(self) -> torch.nn.Module:
        """The online network on the CPU (a copy if it lives elsewhere), for checkpoints."""
        if self.device.type == "cpu":
            return self.q
        model = DQN(self.q.config)
        model.load_state_dict({k: v.cpu() for k, v in self.q.state_dict().items()})
        return model

    def state_dict(self) -> dict:
        """Everything needed to resume learning (weights, target, optimiser, update count)."""
        return {
            "q": self.q.state_dict(),
            "target": self.target.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "n_updates": self.n_updates,
        }

    def load_state_dict(self, state: dict) -> None:
        self.q.load_state_dict(state["q"])
        self.target.load_state_dict(state["target"])
        self.optimizer.load_state_dict(state["optimizer"])  # moves its state to the params' device
        self.n_updates = int(state["n_updates"])
