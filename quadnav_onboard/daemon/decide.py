"""The DQN side of a step, split so that most of it runs before the step boundary.

When a depth frame arrives, :meth:`Decider.prepare` preprocesses it and runs the network's depth
lane on the depth stack the observation history *would* hold with it (without pushing). At the
step boundary, :meth:`Decider.decide` finds that prepared frame: if it is the newest frame and the
history has not changed since, only the position lane and the head run; otherwise (not prepared
yet, or prepared against an older history) the whole decision runs as before. Both give the same
action and Q-values: ``Policy.act_from_features(Policy.depth_features(d), r) == Policy.act(d, r)``.

Every method runs in the daemon's one DQN executor thread, so the history and the prepared slot are
touched by that thread only (no locks).
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

__all__ = ["Decider", "Decision", "PreparedFrame"]


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
    path: Literal["prepared", "full"]
    """``prepared``: the frame's depth lane had already run; ``full``: the whole network ran now."""


class Decider:
    """The observation history, the policy, and the newest prepared frame (latest wins)."""

    def __init__(self, policy: Policy, preprocess: PreprocessConfig) -> None:
        self.policy = policy
        self.preprocess = preprocess
        self.history = ObservationHistory(policy.depth_history, policy.position_history)
        self.prepared: PreparedFrame | None = None

    def prepare(self, frame: DepthFrame) -> PreparedFrame:
        """Preprocess ``frame`` and run the depth lane; keep the result as the newest prepared frame.

        Raises :class:`quadnav_onboard.preprocess.DepthFrameError` for an unusable frame.
        """
        depth_in = preprocess_depth_mm(frame.depth_mm, self.preprocess)
        features = self.policy.depth_features(self.history.depth_with(depth_in))
        self.prepared = PreparedFrame(frame, depth_in, features, self.history.version)
        return self.prepared

    def decide(self, frame: DepthFrame, rel_pos_body_m: ArrayLike) -> Decision:
        """Push (``frame``'s input, ``rel_pos_body_m``) into the history and pick the action.

        Uses the prepared frame when it is ``frame`` and still current, else runs everything.
        Raises :class:`quadnav_onboard.preprocess.DepthFrameError` for an unusable frame.
        """
        p = self.prepared
        if p is not None and p.frame is frame and p.history_version == self.history.version:
            self.history.push(p.depth_input, rel_pos_body_m)
            action, q = self.policy.act_from_features(p.features, self.history.rel_array())
            return Decision(action, q, p.depth_input, "prepared")
        depth_in = preprocess_depth_mm(frame.depth_mm, self.preprocess)
        self.history.push(depth_in, rel_pos_body_m)
        action, q = self.policy.act(*self.history.arrays())
        return Decision(action, q, depth_in, "full")
