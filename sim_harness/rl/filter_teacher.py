"""The flown product as a teacher: a frozen network with the depth safety filter in front of it.

The filter (:mod:`quadnav_onboard.shield`) sees only what the vehicle saw (its remembered depth
views, the floor), so unlike the privileged :class:`~sim_harness.rl.teacher.Teacher` it asks
nothing of the student that its inputs cannot in principle tell. In every visited state the
label is the expert network's Q-values with the primitives the filter vetoes there pushed
``veto_margin`` below the lowest one it allows (:func:`veto_targets`): the arg-max of the label is
the action the product flies (:func:`~quadnav_onboard.policy.masked_argmax`), and the order of
the allowed ones, which the filter falls back on, is the expert's. The student regresses its
Q-values onto the label (Huber), so the result is still a Q-function on the expert's scale and
the RL episodes can follow from it.

The env must run the filter (``EnvConfig.shield.enabled``): its ``allowed`` is the verdict at the
next decision, computed from the views of the flight so far, whoever flew it.
"""

from __future__ import annotations

import copy

import numpy as np
import torch
from numpy.typing import NDArray

from quadnav_onboard.policy import masked_argmax
from sim_harness.env import VecQuadNavEnv
from sim_harness.rl.imitation import Labels

__all__ = ["FilterTeacher", "veto_targets"]


def veto_targets(q: NDArray, allowed: NDArray[np.bool_], margin: float) -> NDArray[np.float32]:
    """``q`` (N, A) with every action not ``allowed`` set ``margin`` below the lowest allowed value
    of its row; a row with none allowed is left as it is (the filter then takes the arg-max of
    all, :func:`~quadnav_onboard.policy.masked_argmax`)."""
    q = np.asarray(q, dtype=np.float32)
    allowed = np.asarray(allowed, dtype=bool)
    if q.shape != allowed.shape:
        raise ValueError(f"q {q.shape} and allowed {allowed.shape} differ in shape")
    if not margin > 0:
        raise ValueError(f"veto margin must be > 0, got {margin}")
    any_allowed = allowed.any(axis=1, keepdims=True)
    lowest = np.where(allowed, q, np.inf).min(axis=1, keepdims=True)
    floor = np.where(any_allowed, lowest - margin, 0.0)
    return np.where(allowed | ~any_allowed, q, floor).astype(np.float32)


class FilterTeacher:
    """Labels states with a frozen copy of ``model`` behind the env's filter."""

    loss = "huber"
    """How the student fits the labels (:func:`sim_harness.rl.imitation.fit`)."""

    def __init__(self, model: torch.nn.Module, veto_margin: float = 1.0, device: str = "cpu") -> None:
        if not veto_margin > 0:
            raise ValueError(f"veto margin must be > 0, got {veto_margin}")
        self.model = copy.deepcopy(model).to(device).eval()
        for p in self.model.parameters():
            p.requires_grad_(False)
        self.veto_margin = float(veto_margin)
        self.device = torch.device(device)

    def q_values(self, depth: NDArray, rel: NDArray, scale_m: float | None = None) -> NDArray[np.float32]:
        """The expert's Q-values; ``scale_m``, the primitive scale flown, for an expert that reads
        it (``NetworkConfig.scale_input``)."""
        with torch.inference_mode():
            d = torch.as_tensor(depth, dtype=torch.float32, device=self.device)
            r = torch.as_tensor(rel, dtype=torch.float32, device=self.device)
            return self.model(d, r, scale_m).cpu().numpy()

    def label(
        self, env: VecQuadNavEnv, depth: NDArray, rel: NDArray, temperature_m: float
    ) -> Labels:
        """Targets (N, A) and the product's actions (N,) for the env's current states; every
        label carries the filter's verdicts."""
        del temperature_m  # the labels are Q-values, not a distribution
        if env.memory is None:
            raise ValueError("the filter teacher needs the env's filter on (EnvConfig.shield.enabled)")
        q = self.q_values(depth, rel, env.config.primitives.scale_m)
        return Labels(veto_targets(q, env.allowed, self.veto_margin), masked_argmax(q, env.allowed),
                      np.zeros(q.shape[0], dtype=bool))
