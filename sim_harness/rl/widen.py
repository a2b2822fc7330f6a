"""A trained network's weights for a network with a longer input history, or wider layers.

A network of ``depth_history`` k (``position_history`` p) reads its last k depth frames (p
relative positions), oldest first. :func:`widen_history` gives the same network with a longer
history the extra, older inputs with zero weights: it computes exactly what the trained one
does, and training (e.g. DAgger from the trained network behind its filter) can then teach it to
use the older frames, the views of obstacles that have left the camera's field of view.

:func:`widen` also widens every hidden layer (``NetworkConfig.width``): each layer keeps its
trained units, and its new units get a fresh random initialisation of their inputs while every
trained unit reads them at zero weight, so the wider network too computes exactly what the
trained one does, and the new units start to learn from the first gradient.

:func:`widen` also adds the scale lane (``NetworkConfig.scale_input``) to a network without one:
the lane gets a fresh random initialisation and the position merge reads it at zero weight, so
the network computes what the trained one does at every scale until training teaches it to tell
the scales apart.
"""

from __future__ import annotations

import dataclasses

import torch

from quadnav_onboard.network import DQN, NetworkConfig

__all__ = ["can_widen", "widen", "widen_history"]

_POSITION_LANES = ("pos_x", "pos_y", "pos_z")


def can_widen(source: NetworkConfig, target: NetworkConfig) -> bool:
    """Whether ``target`` is ``source`` with a depth and position history at least as long,
    hidden layers at least as wide, and perhaps the scale lane added."""
    same_otherwise = dataclasses.replace(
        source, depth_history=target.depth_history, position_history=target.position_history,
        width=target.width, scale_input=target.scale_input, scale_range_m=target.scale_range_m,
    ) == target
    return (
        same_otherwise
        and target.depth_history >= source.depth_history
        and target.position_history >= source.position_history
        and target.width >= source.width
        and target.scale_input >= source.scale_input
        and (not source.scale_input or source.scale_range_m == target.scale_range_m)
    )


def widen_history(model: DQN, target: NetworkConfig) -> dict[str, torch.Tensor]:
    """``model``'s state dict for a :class:`DQN` of config ``target``: the first depth
    convolution and the three position lanes get zero weights on the older inputs prepended
    (histories are oldest first), every other tensor is copied. Raises ValueError when
    ``target`` differs from the model's config by more than longer histories."""
    source = model.config
    if not can_widen(source, target) or target.width != source.width \
            or (target.scale_input, target.scale_range_m) != (source.scale_input, source.scale_range_m):
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


_CONCATENATED = {"pos_merge.0": ("pos_x.0", "pos_y.0", "pos_z.0"), "trunk.0": ("depth_lane.9", "pos_merge.0")}
"""The layers whose input joins other layers' outputs, in :meth:`DQN.q_from_features`'s order."""


def _trained_inputs(layer: str, narrow: dict[str, torch.Tensor],
                    wide: dict[str, torch.Tensor]) -> torch.Tensor:
    """Where a layer's trained inputs sit among its wide inputs. Each layer's trained units come
    first among its units (a flattened convolution's too: channel by channel), so an input that
    is one layer's output keeps its first positions, and a joined input keeps the first
    positions of each part, at the part's wide offset."""
    if layer not in _CONCATENATED:
        return torch.arange(narrow[f"{layer}.weight"].shape[1])
    parts, offset = [], 0
    for part in _CONCATENATED[layer]:
        parts.append(torch.arange(narrow[f"{part}.weight"].shape[0]) + offset)
        offset += wide[f"{part}.weight"].shape[0]
    return torch.cat(parts)


def widen(model: DQN, target: NetworkConfig, seed: int = 0) -> dict[str, torch.Tensor]:
    """``model``'s state dict for a :class:`DQN` of config ``target``, whose histories may be
    longer (:func:`widen_history`) and whose hidden layers may be wider (``width``; from the
    paper's width only). The new units' input weights and biases are those of a fresh
    :class:`DQN` of ``target`` initialised under ``torch.manual_seed(seed)`` (the global
    generator is left as it was); the trained units read the new ones at zero weight. Raises
    ValueError when ``target`` is not such a widening of the model's config. The scale lane, when
    ``target`` adds it, is initialised as a new unit is, and read at zero weight."""
    source = model.config
    if not can_widen(source, target):
        raise ValueError(
            f"cannot widen a network of {source} to {target}: only longer depth and position "
            "histories, wider hidden layers and the scale lane can be added"
        )
    add_scale = target.scale_input and not source.scale_input
    if add_scale and target.width != source.width:
        raise ValueError(f"cannot widen a network of {source} to {target}: add the scale lane "
                         "or widen the layers, one at a time")
    if add_scale:
        unlaned = dataclasses.replace(target, scale_input=False, scale_range_m=None)
        return _add_scale_lane(widen_history(model, unlaned), target, seed)
    if target.width == source.width:
        return widen_history(model, target)
    if source.width != 1:
        raise ValueError(f"cannot widen a network of width {source.width}: only the paper's width 1 widens")
    if source.scale_input:
        raise ValueError("cannot widen the layers of a network that reads the scale: widen them first")
    narrow = widen_history(model, dataclasses.replace(target, width=1))
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        fresh = DQN(target).state_dict()
    state: dict[str, torch.Tensor] = {}
    for layer in (key.removesuffix(".weight") for key in fresh if key.endswith(".weight")):
        w_old, b_old = narrow[f"{layer}.weight"], narrow[f"{layer}.bias"]
        w_new, b_new = fresh[f"{layer}.weight"].clone(), fresh[f"{layer}.bias"].clone()
        rows = torch.arange(w_old.shape[0])  # the trained units come first (the outputs: all)
        w_new[rows] = 0.0  # a trained unit reads every new unit at zero weight ...
        cols = _trained_inputs(layer, narrow, fresh)
        w_new[rows[:, None], cols] = w_old  # ... and its trained inputs as it did
        b_new[rows] = b_old
        state[f"{layer}.weight"], state[f"{layer}.bias"] = w_new, b_new
    if set(state) != set(fresh):
        raise AssertionError(f"widen: tensors not covered: {sorted(set(fresh) - set(state))}")
    return state


def _add_scale_lane(state: dict[str, torch.Tensor], target: NetworkConfig,
                    seed: int) -> dict[str, torch.Tensor]:
    """``state`` (a network of ``target`` without the scale lane) with the lane of a fresh
    :class:`DQN` of ``target`` (``torch.manual_seed(seed)``, the global generator left as it was)
    and the position merge reading it at zero weight (its inputs last, as in
    :meth:`DQN.q_from_features`)."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        fresh = DQN(target).state_dict()
    out = dict(state)
    out["pos_scale.0.weight"] = fresh["pos_scale.0.weight"].clone()
    out["pos_scale.0.bias"] = fresh["pos_scale.0.bias"].clone()
    merge = state["pos_merge.0.weight"]
    extra = fresh["pos_merge.0.weight"].shape[1] - merge.shape[1]
    zeros = torch.zeros((merge.shape[0], extra), dtype=merge.dtype)
    out["pos_merge.0.weight"] = torch.cat([merge, zeros], dim=1)
    if set(out) != set(fresh):
        raise AssertionError(f"widen: tensors not covered: {sorted(set(fresh) ^ set(out))}")
    return out
