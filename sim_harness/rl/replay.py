"""Experience replay: a fixed-capacity ring of transitions and an n-step return accumulator.

Depth observations are stored as float16 (resolution ~5 mm at 10 m on the [0, 1] scale) to halve
memory; everything else as float32. A transition is ``(depth, rel, action, reward, next_depth,
next_rel, done, n)`` where ``reward`` is the (possibly n-step) discounted return, ``n`` the number
of steps it spans and ``done`` whether the episode terminated inside it (no bootstrap). Sampling
uses the buffer's own seeded numpy Generator. Memory is bounded by ``capacity``.

:class:`PrioritizedReplayBuffer` (beyond the paper) samples in proportion to each transition's last
TD error (Schaul et al. 2016, "Prioritized Experience Replay", proportional variant) and returns
the importance-sampling weights that correct the bias. Sampling draws from the cumulative sum of
the priorities, O(capacity) per minibatch: for the 200k-transition buffers used here 0.65 ms of a
7.6 ms draw against 6.7 ms for a uniform one (``benchmarks/bench_replay.py``, 2-core VM), so no
sum tree is needed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

__all__ = ["Batch", "NStepAccumulator", "PrioritizedReplayBuffer", "ReplayBuffer"]


@dataclass
class Batch:
    """A sampled minibatch (numpy, float32 unless stated)."""

    depth: NDArray[np.float32]
    """(B, k_d, 32, 32) depth inputs in [0, 1]."""
    rel: NDArray[np.float32]
    """(B, k_p, 3) relative positions, heading frame, m."""
    action: NDArray[np.int64]
    """(B,) action indices."""
    reward: NDArray[np.float32]
    """(B,) discounted return over ``n`` steps."""
    next_depth: NDArray[np.float32]
    next_rel: NDArray[np.float32]
    done: NDArray[np.float32]
    """(B,) 1.0 if the episode terminated (collision, deviation, goal): no bootstrap."""
    n: NDArray[np.float32]
    """(B,) number of environment steps the transition spans (bootstrap with γ**n)."""
    index: NDArray[np.int64]
    """(B,) slots in the buffer."""
    next_allowed: NDArray[np.bool_] | None = None
    """(B, n_actions) actions the shield allowed in the next state (the target's max runs over
    them); None when every action was allowed."""
    weight: NDArray[np.float32] | None = None
    """(B,) importance-sampling weights of a prioritised sample (largest 1); None = uniform."""


class ReplayBuffer:
    """Uniform replay over the last ``capacity`` transitions."""

    def __init__(
        self,
        capacity: int,
        depth_shape: tuple[int, ...],
        rel_shape: tuple[int, ...],
        seed: int,
        n_actions: int = 18,
    ) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.depth = np.zeros((capacity, *depth_shape), dtype=np.float16)
        self.next_depth = np.zeros((capacity, *depth_shape), dtype=np.float16)
        self.rel = np.zeros((capacity, *rel_shape), dtype=np.float32)
        self.next_rel = np.zeros((capacity, *rel_shape), dtype=np.float32)
        self.action = np.zeros(capacity, dtype=np.int64)
        self.reward = np.zeros(capacity, dtype=np.float32)
        self.done = np.zeros(capacity, dtype=np.float32)
        self.n = np.ones(capacity, dtype=np.float32)
        self.next_allowed = np.ones((capacity, n_actions), dtype=bool)
        self._masked = False
        self.rng = np.random.default_rng(seed)
        self._next = 0
        self._size = 0

    def __len__(self) -> int:
        return self._size

    def add(
        self,
        depth: NDArray,
        rel: NDArray,
        action: NDArray,
        reward: NDArray,
        next_depth: NDArray,
        next_rel: NDArray,
        done: NDArray,
        n: NDArray | None = None,
        next_allowed: NDArray | None = None,
    ) -> NDArray[np.int64]:
        """Store a batch of M transitions (leading axis M on every array); ``next_allowed``
        (M, n_actions) defaults to every action allowed. Returns the slots written."""
        m = len(action)
        if m == 0:
            return np.zeros(0, dtype=np.int64)
        if m > self.capacity:
            raise ValueError(f"cannot add {m} transitions to a buffer of capacity {self.capacity}")
        idx = (self._next + np.arange(m)) % self.capacity
        self.depth[idx] = depth
        self.rel[idx] = rel
        self.action[idx] = action
        self.reward[idx] = reward
        self.next_depth[idx] = next_depth
        self.next_rel[idx] = next_rel
        self.done[idx] = done
        self.n[idx] = 1.0 if n is None else n
        self.next_allowed[idx] = True if next_allowed is None else next_allowed
        self._masked |= next_allowed is not None
        self._next = int((self._next + m) % self.capacity)
        self._size = min(self._size + m, self.capacity)
        return idx

    def sample(self, batch_size: int) -> Batch:
        """A uniform minibatch (with replacement) of stored transitions."""
        if self._size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        return self._batch(self.rng.integers(0, self._size, size=batch_size))

    def update_priorities(self, index: NDArray[np.int64], td_abs: NDArray) -> None:
        """Uniform replay keeps no priorities (:class:`PrioritizedReplayBuffer` does)."""

    def _batch(self, idx: NDArray[np.int64]) -> Batch:
        return Batch(
            depth=self.depth[idx].astype(np.float32),
            rel=self.rel[idx],
            action=self.action[idx],
            reward=self.reward[idx],
            next_depth=self.next_depth[idx].astype(np.float32),
            next_rel=self.next_rel[idx],
            done=self.done[idx],
            n=self.n[idx],
            index=idx,
            next_allowed=self.next_allowed[idx] if self._masked else None,
        )


class NStepAccumulator:
    """Turns per-env 1-step transitions into n-step ones (n = 1 passes them through).

    ``push`` takes one vectorised step of N envs (obs before the step, action, reward, obs after,
    terminated, truncated) and the current γ; it returns the transitions ready for the buffer as a
    dict of stacked arrays (possibly empty). At an episode end the pending partial returns are
    flushed, bootstrapping from the final observation unless the episode terminated.
    """

    def __init__(self, n_envs: int, n_step: int) -> None:
        if n_step < 1:
            raise ValueError(f"n_step must be >= 1, got {n_step}")
        self.n_step = int(n_step)
        self.pending: list[deque] = [deque() for _ in range(n_envs)]

    def push(
        self,
        depth: NDArray,
        rel: NDArray,
        action: NDArray,
        reward: NDArray,
        next_depth: NDArray,
        next_rel: NDArray,
        terminated: NDArray,
        truncated: NDArray,
        gamma: float,
        next_allowed: NDArray | None = None,
    ) -> dict[str, NDArray]:
        if self.n_step == 1:  # fast path: every step is a transition
            extra = {} if next_allowed is None else {"next_allowed": np.asarray(next_allowed)}
            return extra | {
                "depth": depth,
                "rel": rel,
                "action": np.asarray(action),
                "reward": np.asarray(reward),
                "next_depth": next_depth,
                "next_rel": next_rel,
                "done": np.asarray(terminated, dtype=np.float32),
                "n": np.ones(len(action), np.float32),
            }
        out: list[tuple] = []
        for i, q in enumerate(self.pending):
            q.append((depth[i], rel[i], int(action[i]), float(reward[i])))
            end = bool(terminated[i] or truncated[i])
            while q and (len(q) >= self.n_step or end):
                ret = 0.0
                for k, (_, _, _, r) in enumerate(q):
                    ret += (gamma**k) * r
                d0, r0, a0, _ = q[0]
                nxt = None if next_allowed is None else next_allowed[i]
                out.append((d0, r0, a0, ret, next_depth[i], next_rel[i], float(terminated[i]), len(q), nxt))
                q.popleft()
                if not end:
                    break
        if not out:
            return {}
        cols = list(zip(*out, strict=True))
        names = ("depth", "rel", "action", "reward", "next_depth", "next_rel", "done", "n", "next_allowed")
        stacked = ("depth", "rel", "next_depth", "next_rel", "next_allowed")
        batch = {
            name: np.stack(col) if name in stacked else np.asarray(col)
            for name, col in zip(names, cols, strict=True)
            if name != "next_allowed" or next_allowed is not None
        }
        return batch


class PrioritizedReplayBuffer(ReplayBuffer):
    """Proportional prioritised replay: P(i) = p_i^α / Σ p^α with p_i = |TD error_i| + ``eps``;
    new transitions get the largest priority so far, so each is replayed at least about once."""

    def __init__(
        self,
        capacity: int,
        depth_shape: tuple[int, ...],
        rel_shape: tuple[int, ...],
        seed: int,
        n_actions: int = 18,
        alpha: float = 0.6,
        eps: float = 1e-3,
    ) -> None:
        super().__init__(capacity, depth_shape, rel_shape, seed, n_actions)
        if not alpha >= 0 or not eps > 0:
            raise ValueError(f"need alpha >= 0 and eps > 0, got {alpha} and {eps}")
        self.alpha, self.eps = float(alpha), float(eps)
        self.priority = np.zeros(capacity, dtype=np.float64)
        """p_i^α of every slot (0 for empty slots: never sampled)."""
        self._max_priority = 1.0
        self.beta = 0.4
        """Importance-sampling exponent of the next samples (1 corrects the sampling bias fully);
        the trainer anneals it (``TrainConfig.per_beta_start`` -> 1)."""

    def add(self, *args, **kwargs) -> NDArray[np.int64]:  # type: ignore[no-untyped-def]
        idx = super().add(*args, **kwargs)
        self.priority[idx] = self._max_priority**self.alpha
        return idx

    def sample(self, batch_size: int) -> Batch:
        """A minibatch drawn in proportion to priority, with weights (N P(i))^-β / max_j (N P(j))^-β,
        β = :attr:`beta`."""
        if self._size == 0:
            raise ValueError("cannot sample from an empty replay buffer")
        cum = np.cumsum(self.priority[: self._size])
        total = cum[-1]
        idx = np.searchsorted(cum, self.rng.random(batch_size) * total, side="right")
        idx = np.minimum(idx, self._size - 1)
        prob = self.priority[idx] / total
        weight = (self._size * prob) ** (-self.beta)
        batch = self._batch(idx)
        batch.weight = (weight / weight.max()).astype(np.float32)
        return batch

    def update_priorities(self, index: NDArray[np.int64], td_abs: NDArray) -> None:
        """Set the priorities of the sampled slots from their new |TD errors|."""
        p = np.abs(np.asarray(td_abs, dtype=np.float64)) + self.eps
        self.priority[index] = p**self.alpha
        self._max_priority = max(self._max_priority, float(p.max()))
