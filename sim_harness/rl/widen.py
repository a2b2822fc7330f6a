"""A trained network's weights for a network with a longer input history.

A network of ``depth_history`` k (``position_history`` p) reads its last k depth frames (p
relative positions), oldest first. :func:`widen_history` gives the same network with a longer
history the extra, older inputs with zero weights: it computes exactly what the trained one
does, and training (e.g. DAgger from the trained network behind its filter) can then teach it to
use the older frames, the views of obstacles that have left the camera's field of view.
"""

from __future__ import annotations

import dataclasses

import torch

from quadnav_onboard.network import DQN, NetworkConfig

__all__ = ["can_widen", "widen_history"]

_POSITION_LANES = ("pos_x", "pos_y", "pos_z")


def can_widen(source: NetworkConfig, target: NetworkConfig) -> bool:
    """Whether ``target`` is ``source`` with a depth and position history at least as long."""
    same_otherwise = dataclasses.replace(
        source, depth_history=target.depth_history, position_history=target.position_history
    ) == target
    return (
        same_otherwise
        and target.depth_history >= source.depth_history
        and target.position_history >= source.position_history
    )


def widen_history(model: DQN, target: NetworkConfig) -> dict[str, torch.Tensor]:
    """``model``'s state dict for a :class:`DQN` of config ``target``: the first depth
    convolution and the three position lanes get zero weights on the older inputs prepended
    (histories are oldest first), every other tensor is copied. Raises ValueError when
    ``target`` differs from the model's config by more than longer histories."""
    source = model.config
    if not can_widen(source, target):
        raise ValueError(
            f"cannot widen a network of {source} to {target}: only longer depth and position "
            "histories can be added"
        )
    state = {k: v.detach().clone() for k, v in model.state_dict().items()}

    def prepend_zeros(key: str, extra: int) -> None:
        w = state[key]  # (out, in, ...): inputs on dim 1
        zeros = torch.zeros((w.shape[0], extra, *w.shape[2:]), dtype=w.dtype)
        state[key] = torch.cat([zeros, w], dim=1)

    prepend_zeros("depth_lane.0.weight", target.depth_history - source.depth_history)
    for lane in _POSITION_LANES:
        prepend_zeros(f"{lane}.0.weight", target.position_history - source.position_history)
    return state
