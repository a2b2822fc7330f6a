"""The DQN side of a step, split so that the heavy half runs before the step boundary.

When a depth frame arrives, :meth:`Decider.prepare` (in the DQN executor thread) preprocesses it and
runs the network's depth lane on the depth stack the observation history *would* hold with it. At
the step boundary, :meth:`Decider.decide` (on the event loop) pushes the prepared input into the
history and runs only the position lane and the head (~0.1-0.6 ms), provided the prepared frame is
the newest one and the history has not changed since (:meth:`Decider.current`). Otherwise the
daemon prepares the newest frame first, in the executor, and then decides: the same result either
way, since ``Policy.act_from_features(Policy.depth_features(d), r) == Policy.act(d, r)``.

Threads: the history lives on the event loop (read and pushed there only); a preparation gets its
own copy (:meth:`Decider.snapshot`), and hands its result back by replacing ``prepared`` (one
reference), so nothing needs a lock.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.observation import ObservationHistory
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.sources.base import DepthFrame

__all__ = ["Decider", "Decision", "DecisionPath", "PreparedFrame"]

DecisionPath = Literal["prepared", "waited", "full"]
"""How a step got its prepared frame: ready at the step boundary; being prepared at the boundary
(awaited); or prepared at the boundary (preprocessing and the whole network ran in the step)."""


@dataclass(frozen=True)
class PreparedFrame:
    """One depth frame, preprocessed and through the depth lane."""

    frame: DepthFrame
    depth_input: NDArray[np.float32]
    """The network's depth input for this frame, float32 (32, 32) in [0, 1]."""
    features: NDArray[np.float32]
    """Depth-lane features of the history's last k_d - 1 inputs and this one, float32 (64,)."""
    history_version: int
    """``ObservationHistory.version`` they were computed against."""


@dataclass(frozen=True)
class Decision:
    """The outcome of one step's decision."""

    action: int
    q: NDArray[np.float32]
    """Q-values, shape (n_actions,)."""
    depth_input: NDArray[np.float32]
    """The depth input pushed into the history (what the network saw last), (32, 32)."""
    path: DecisionPath


class Decider:
    """The observation history, the policy, and the newest prepared frame (latest wins)."""

    def __init__(self, policy: Policy, preprocess: PreprocessConfig) -> None:
        self.policy = policy
        self.preprocess = preprocess
        self.history = ObservationHistory(policy.depth_history, policy.position_history)
        self.prepared: PreparedFrame | None = None

    def snapshot(self) -> ObservationHistory:
        """Loop side: a copy of the history for one preparation."""
        return self.history.copy()

    def prepare(self, frame: DepthFrame, history: ObservationHistory) -> PreparedFrame:
        """Executor side: preprocess ``frame``, run the depth lane on ``history`` (a snapshot) plus
        this input, and keep the result as the newest prepared frame.

        Raises :class:`quadnav_onboard.preprocess.DepthFrameError` for an unusable frame.
        """
        depth_in = preprocess_depth_mm(frame.depth_mm, self.preprocess)
        features = self.policy.depth_features(history.depth_with(depth_in))
        prepared = PreparedFrame(frame, depth_in, features, history.version)
        self.prepared = prepared
        return prepared

    def current(self, frame: DepthFrame) -> PreparedFrame | None:
        """The prepared frame if it is ``frame`` and was prepared against the history as it is now."""
        p = self.prepared
        if p is not None and p.frame is frame and p.history_version == self.history.version:
            return p
        return None

    def decide(self, prepared: PreparedFrame, rel_pos_body_m: ArrayLike, path: DecisionPath) -> Decision:
        """Loop side: push (the prepared input, ``rel_pos_body_m``) and pick the action (head only)."""
        if prepared.history_version != self.history.version:
            raise RuntimeError("decide() with a frame prepared against an older history")
        self.history.push(prepared.depth_input, rel_pos_body_m)
        action, q = self.policy.act_from_features(prepared.features, self.history.rel_array())
        return Decision(action, q, prepared.depth_input, path)
