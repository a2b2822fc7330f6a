"""Save and load Q-network checkpoints.

A checkpoint is a ``torch.save`` dict loaded with ``weights_only=True`` (no pickled code):
``{"format": "quadnav-dqn", "format_version": 1, "network": {...NetworkConfig...},
"primitives": {...}, "preprocess": {...}, "state_dict": {...}, "meta": {...}}``.
Every way a file can be wrong raises :class:`CheckpointError` naming the file and the problem.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import torch

from quadnav_onboard.network import DQN, NetworkConfig

__all__ = ["FORMAT_VERSION", "Checkpoint", "CheckpointError", "load_checkpoint", "save_checkpoint"]

FORMAT = "quadnav-dqn"
FORMAT_VERSION = 1


class CheckpointError(ValueError):
    """A checkpoint file is missing, corrupt, truncated or does not match what is expected."""


@dataclass
class Checkpoint:
    """A loaded checkpoint: the network (in eval mode) and what was saved with it."""

    model: DQN
    network: NetworkConfig
    primitives: dict[str, Any] = field(default_factory=dict)
    preprocess: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    sha256: str = ""


def save_checkpoint(
    path: str | Path,
    model: DQN,
    *,
    primitives: dict[str, Any] | None = None,
    preprocess: dict[str, Any] | None = None,
    meta: dict[str, Any] | None = None,
) -> Path:
    """Write ``model`` and its configuration to ``path`` atomically (write, then rename)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "network": model.config.to_dict(),
        "primitives": primitives or {},
        "preprocess": preprocess or {},
        "meta": meta or {},
        "state_dict": model.state_dict(),
    }
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(payload, tmp)
    tmp.replace(path)
    return path


def load_checkpoint(path: str | Path, expect: NetworkConfig | None = None) -> Checkpoint:
    """Load a checkpoint; if ``expect`` is given, its network shape must match exactly."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: checkpoint file not found")
    raw = path.read_bytes()
    try:
        import io

        payload = torch.load(io.BytesIO(raw), map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for bad bytes
        raise CheckpointError(
            f"{path}: not a readable checkpoint (corrupt or truncated?): {type(exc).__name__}: {exc}"
        ) from exc
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path}: not a quadnav DQN checkpoint (no format '{FORMAT}')")
    version = payload.get("format_version")
    if version != FORMAT_VERSION:
        raise CheckpointError(
            f"{path}: format_version {version!r} is not supported (this build reads {FORMAT_VERSION})"
        )
    net_dict = payload.get("network")
    known = {f.name for f in fields(NetworkConfig)}
    if not isinstance(net_dict, dict) or set(net_dict) - known:
        raise CheckpointError(f"{path}: bad 'network' section {net_dict!r}")
    try:
        net_cfg = NetworkConfig(**net_dict)
    except (TypeError, ValueError) as exc:
        raise CheckpointError(f"{path}: bad 'network' section: {exc}") from exc
    if expect is not None and net_cfg != expect:
        raise CheckpointError(f"{path}: network {net_cfg} does not match the expected {expect}")
    model = DQN(net_cfg)
    try:
        model.load_state_dict(payload["state_dict"], strict=True)
    except (KeyError, RuntimeError) as exc:
        raise CheckpointError(f"{path}: weights do not fit the network {net_cfg}: {exc}") from exc
    for name, tensor in model.state_dict().items():
        if not torch.isfinite(tensor).all():
            raise CheckpointError(f"{path}: weights '{name}' contain NaN or Inf")
    model.eval()
    return Checkpoint(
        model=model,
        network=net_cfg,
        primitives=dict(payload.get("primitives") or {}),
        preprocess=dict(payload.get("preprocess") or {}),
        meta=dict(payload.get("meta") or {}),
        sha256=hashlib.sha256(raw).hexdigest(),
    )
