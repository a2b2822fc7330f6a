"""The greedy policy: a loaded checkpoint that maps an observation to a motion primitive.

``Policy.act(depth, rel)`` runs the Q-network once without gradients and returns the arg-max
action and the Q-values. Inputs are the arrays of :class:`quadnav_onboard.observation.ObservationHistory`:
depth (k_d, 32, 32) float32 in [0, 1] and rel (k_p, 3) float32, metres, heading frame, oldest first.

The same decision in two halves, for the flight daemon (which runs the depth half when a frame
arrives): ``act_from_features(depth_features(depth), rel)`` equals ``act(depth, rel)``.
``allowed`` (optional, bool (n_actions,)) restricts the arg-max to the allowed actions; when none
is allowed it is ignored (arg-max over all actions), so the policy always returns an action.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray

from quadnav_onboard.checkpoint import Checkpoint, load_checkpoint
from quadnav_onboard.config import PrimitiveConfig, parse_config
from quadnav_onboard.preprocess import PreprocessConfig
from quadnav_onboard.primitives import PrimitiveSet

__all__ = ["DEFAULT_MODEL_PATH", "Policy", "masked_argmax"]

DEFAULT_MODEL_PATH = Path(__file__).resolve().parent / "models" / "default.pt"
"""The shipped checkpoint the daemon and ``quadnav-sim eval`` load by default."""

PGUD_MODEL_PATH = DEFAULT_MODEL_PATH.with_name("pgud.pt")
"""The bundled model until 0.5.0, kept as the imitation recipes' ``init_model`` (recipes/pgud.yaml)."""
PRIVILEGED_LAB_HINGE_MODEL_PATH = DEFAULT_MODEL_PATH.with_name("privileged-lab-hinge.pt")
"""The bundled model from 0.5.1 to 0.5.6 (recipes/privileged-lab-hinge.yaml's seed 0), kept as the
second-round recipes' ``init_model``."""


def masked_argmax(q: ArrayLike, allowed: ArrayLike | None) -> NDArray[np.int64]:
    """Arg-max over the last axis among the ``allowed`` actions (same shape as ``q``, bool); a row
    with no allowed action, or ``allowed`` None, takes the arg-max over all of them. The one rule
    the flight daemon, evaluation and training share."""
    qa = np.asarray(q)
    if allowed is None:
        return np.argmax(qa, axis=-1).astype(np.int64)
    mask = np.asarray(allowed, dtype=bool)
    mask = mask | ~mask.any(axis=-1, keepdims=True)
    return np.argmax(np.where(mask, qa, -np.inf), axis=-1).astype(np.int64)


class Policy:
    """Greedy action selection with a loaded :class:`Checkpoint` (network in eval mode)."""

    def __init__(self, checkpoint: Checkpoint) -> None:
        self.checkpoint = checkpoint
        self.model = checkpoint.model
        self.model.eval()
        self.network = checkpoint.network
        self.depth_history = checkpoint.network.depth_history
        self.position_history = checkpoint.network.position_history
        self.n_actions = checkpoint.network.n_actions

    @classmethod
    def from_path(cls, path: str | Path = DEFAULT_MODEL_PATH) -> Policy:
        """Load a checkpoint file (raises :class:`quadnav_onboard.checkpoint.CheckpointError`)."""
        return cls(load_checkpoint(path))

    def primitive_config(self) -> PrimitiveConfig:
        """The action set the model was trained with (defaults if the checkpoint does not say)."""
        return parse_config(PrimitiveConfig, self.checkpoint.primitives, source="checkpoint.primitives")

    def primitive_set(self) -> PrimitiveSet:
        return self.primitive_config().build()

    def preprocess_config(self) -> PreprocessConfig:
        """The depth preprocessing the model was trained with."""
        return parse_config(PreprocessConfig, self.checkpoint.preprocess, source="checkpoint.preprocess")

    @property
    def reads_scale(self) -> bool:
        """Whether the network reads the primitive scale it flies at: every call then passes
        ``scale_m``, the scale of the primitives flown (not necessarily the one trained with)."""
        return self.network.scale_input

    def q_values_batch(
        self, depth: ArrayLike, rel: ArrayLike, scale_m: float | None = None
    ) -> NDArray[np.float32]:
        """Q-values (B, n_actions) for a batch: depth (B, k_d, 32, 32), rel (B, k_p, 3); ``scale_m``
        the primitive scale flown, for a model that reads it (:attr:`reads_scale`)."""
        d = torch.as_tensor(np.asarray(depth, dtype=np.float32))
        r = torch.as_tensor(np.asarray(rel, dtype=np.float32))
        with torch.inference_mode():
            return self.model(d, r, scale_m).numpy()

    def act(
        self, depth: ArrayLike, rel: ArrayLike, allowed: ArrayLike | None = None, scale_m: float | None = None
    ) -> tuple[int, NDArray[np.float32]]:
        """Greedy action for one observation; returns (action index, Q-values (n_actions,))."""
        return self.act_from_features(self.depth_features(depth), rel, allowed, scale_m)

    def depth_features(self, depth: ArrayLike) -> NDArray[np.float32]:
        """The network's depth lane for one depth stack (k_d, 32, 32): features float32 (64 * width,)."""
        d = np.ascontiguousarray(depth, dtype=np.float32)
        if d.shape != (self.depth_history, 32, 32):
            raise ValueError(f"depth must have shape ({self.depth_history}, 32, 32), got {d.shape}")
        with torch.inference_mode():
            return self.model.depth_features(torch.from_numpy(d[None]))[0].numpy()

    def act_from_features(
        self, features: ArrayLike, rel: ArrayLike, allowed: ArrayLike | None = None,
        scale_m: float | None = None,
    ) -> tuple[int, NDArray[np.float32]]:
        """The rest of the network and the arg-max: features (64 * width,) from :meth:`depth_features`,
        rel (k_p, 3); returns (action index, Q-values (n_actions,)).

        ``allowed``: bool (n_actions,); the arg-max is over the allowed actions only, or over all
        of them if none is allowed. The Q-values returned are all of them, unmasked. ``scale_m``:
        the primitive scale flown, for a model that reads it (:attr:`reads_scale`).
        """
        f = np.ascontiguousarray(features, dtype=np.float32)
        r = np.ascontiguousarray(rel, dtype=np.float32)
        if f.ndim != 1:
            raise ValueError(f"features must be 1-D, got shape {f.shape}")
        if r.shape != (self.position_history, 3):
            raise ValueError(f"rel must have shape ({self.position_history}, 3), got {r.shape}")
        with torch.inference_mode():
            q = self.model.q_from_features(torch.from_numpy(f[None]), torch.from_numpy(r[None]), scale_m)
        q = q[0].numpy()
        if allowed is not None and np.shape(allowed) != (self.n_actions,):
            raise ValueError(f"allowed must have shape ({self.n_actions},), got {np.shape(allowed)}")
        return int(masked_argmax(q, allowed)), q
