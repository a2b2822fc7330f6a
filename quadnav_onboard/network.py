"""The paper's DQN (Camci & Kayacan, Fig. 3), with the options our ablations add.

Depth lane: conv 8@10x10 stride 2 -> ReLU -> conv 16@6x6 -> ReLU -> conv 32@3x3 -> ReLU,
flatten (32*5*5 = 800) -> 64 -> 64. Position lane: x -> 16, y -> 8, z -> 8 (each its own linear
sub-lane), concatenated (32) -> 16. Head: concat (80) -> 64 -> 32 -> n_actions, no activation on the
last layer. All hidden layers use ReLU. With the defaults this has 73,946 parameters.

Options (all off by default = the paper): ``depth_history`` stacks the last k depth frames as
input channels; ``position_history`` feeds the last k relative positions to each sub-lane;
``dueling`` splits the head's last layer into value and advantage streams; ``width`` multiplies
every hidden layer's size (its channels and units), the inputs and outputs staying as they are;
``scale_input`` feeds the primitive scale the network flies at (metres per axis of one primitive)
to a fourth position sub-lane (1 -> 8), so one network can answer differently at 0.5 m and 1 m;
``scale_range_m`` (lo, hi) has that lane read the scale on a log axis centred on the range, lo -> -1
and hi -> +1, instead of in metres.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
from torch import nn

from quadnav_onboard.camera import INPUT_SIZE_PX

__all__ = ["DQN", "NetworkConfig", "count_parameters"]

INPUT_SIZE = INPUT_SIZE_PX
"""Side (pixels) of the square depth input."""


@dataclass(frozen=True)
class NetworkConfig:
    """Shape of the Q-network."""

    __pydantic_config__ = {"extra": "forbid"}  # config files: unknown keys are errors

    n_actions: int = 18
    """Number of motion primitives (outputs)."""
    depth_history: int = 1
    """Depth frames stacked as input channels (1 = the paper)."""
    position_history: int = 1
    """Relative positions fed to each position sub-lane (1 = the paper)."""
    dueling: bool = False
    """Dueling head (value + advantage) instead of the paper's plain head."""
    width: int = 1
    """Every hidden layer's size times this (1 = the paper). Range: 1-4."""
    scale_input: bool = False
    """The network also reads the primitive scale it flies at (m), in its own position sub-lane;
    every caller then passes it (the paper: no)."""
    scale_range_m: tuple[float, float] | None = None
    """With ``scale_input``: the scale lane reads ``(2 log2 s - log2 lo - log2 hi) / (log2 hi - log2 lo)``
    for the scales (lo, hi) it was trained at, -1 at lo and +1 at hi; None: the scale in metres.
    Range: 0 < lo < hi <= 5 (m)."""

    def __post_init__(self) -> None:
        if not (isinstance(self.width, int) and 1 <= self.width <= 4):
            raise ValueError(f"network width must be an integer in 1-4, got {self.width!r}")
        if not isinstance(self.scale_input, bool):
            raise ValueError(f"network scale_input must be true or false, got {self.scale_input!r}")
        if self.scale_range_m is not None:
            r = self.scale_range_m
            ok = (isinstance(r, (tuple, list)) and len(r) == 2
                  and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in r)
                  and all(math.isfinite(v) for v in r) and 0 < r[0] < r[1] <= 5)
            if not ok:
                raise ValueError(f"network scale_range_m must be two scales (m) with 0 < lo < hi <= 5, "
                                 f"got {r!r}")
            if not self.scale_input:
                raise ValueError("network scale_range_m is how the scale lane reads the scale: it needs "
                                 "scale_input: true")
            object.__setattr__(self, "scale_range_m", (float(r[0]), float(r[1])))

    def to_dict(self) -> dict[str, object]:
        """The config as a checkpoint stores it; ``width``, ``scale_input`` and ``scale_range_m``
        only where they are not the paper's, so a checkpoint of the paper's network reads the same
        in builds that predate the keys (and one that reads the scale is refused by them, not
        misread)."""
        d = asdict(self)
        if self.width == 1:
            del d["width"]
        if not self.scale_input:
            del d["scale_input"]
        if self.scale_range_m is None:
            del d["scale_range_m"]
        else:
            d["scale_range_m"] = list(self.scale_range_m)
        return d

    def scale_feature(self, scale_m: torch.Tensor) -> torch.Tensor:
        """What the scale lane reads for ``scale_m`` (m): the scale itself, or with
        ``scale_range_m`` its log, -1 at the range's low end and +1 at its high end."""
        if self.scale_range_m is None:
            return scale_m
        lo, hi = (math.log2(v) for v in self.scale_range_m)
        return (2.0 * torch.log2(scale_m) - lo - hi) / (hi - lo)


class DQN(nn.Module):
    """Q(s, ·) for s = (depth, relative position).

    ``forward(depth, rel_pos, scale_m)``: depth float32 (B, depth_history, 32, 32) in [0, 1];
    rel_pos float32 (B, position_history, 3), metres, heading frame (x fwd, y left, z up), oldest
    first; ``scale_m`` float32 (B,), the primitive scale each row flies at (m): required when
    ``config.scale_input``, ignored otherwise. Returns Q-values (B, n_actions). ``forward`` is
    exactly ``q_from_features(depth_features(depth), rel_pos, scale_m)``.
    """

    def __init__(self, config: NetworkConfig = NetworkConfig()) -> None:
        super().__init__()
        self.config = config
        k_d, k_p, w = config.depth_history, config.position_history, config.width
        self.depth_lane = nn.Sequential(
            nn.Conv2d(k_d, 8 * w, kernel_size=10, stride=2),
            nn.ReLU(),
            nn.Conv2d(8 * w, 16 * w, kernel_size=6),
            nn.ReLU(),
            nn.Conv2d(16 * w, 32 * w, kernel_size=3),
            nn.ReLU(),
            nn.Flatten(),
            nn.Linear(800 * w, 64 * w),
            nn.ReLU(),
            nn.Linear(64 * w, 64 * w),
            nn.ReLU(),
        )
        self.pos_x = nn.Sequential(nn.Linear(k_p, 16 * w), nn.ReLU())
        self.pos_y = nn.Sequential(nn.Linear(k_p, 8 * w), nn.ReLU())
        self.pos_z = nn.Sequential(nn.Linear(k_p, 8 * w), nn.ReLU())
        if config.scale_input:
            self.pos_scale = nn.Sequential(nn.Linear(1, 8 * w), nn.ReLU())
        self.pos_merge = nn.Sequential(nn.Linear((40 if config.scale_input else 32) * w, 16 * w), nn.ReLU())
        self.trunk = nn.Sequential(nn.Linear(80 * w, 64 * w), nn.ReLU(), nn.Linear(64 * w, 32 * w), nn.ReLU())
        if config.dueling:
            self.value = nn.Linear(32 * w, 1)
            self.advantage = nn.Linear(32 * w, config.n_actions)
        else:
            self.out = nn.Linear(32 * w, config.n_actions)

    def forward(self, depth: torch.Tensor, rel_pos: torch.Tensor,
                scale_m: torch.Tensor | float | None = None) -> torch.Tensor:
        return self.q_from_features(self.depth_features(depth), rel_pos, scale_m)

    def depth_features(self, depth: torch.Tensor) -> torch.Tensor:
        """The depth lane alone: depth (B, depth_history, 32, 32) -> features (B, 64 * width).

        With :meth:`q_from_features` this splits :meth:`forward` in two, so the flight daemon can
        run the depth lane when a frame arrives and only the rest at the step boundary.
        """
        return self.depth_lane(depth)

    def q_from_features(self, features: torch.Tensor, rel_pos: torch.Tensor,
                        scale_m: torch.Tensor | float | None = None) -> torch.Tensor:
        """The position lane, trunk and head: features (B, 64 * width), rel_pos (B, position_history, 3),
        scale_m (B,) or one scale for every row, when the network reads the scale -> Q-values
        (B, n_actions). Raises ValueError when that scale is missing, or is not finite and > 0 in
        every row (a row that was never told its scale)."""
        lanes = [self.pos_x(rel_pos[..., 0]), self.pos_y(rel_pos[..., 1]), self.pos_z(rel_pos[..., 2])]
        if self.config.scale_input:
            if scale_m is None:
                raise ValueError("this network reads the primitive scale it flies at: pass scale_m (B,)")
            s = torch.as_tensor(scale_m, dtype=rel_pos.dtype, device=rel_pos.device).reshape(-1, 1)
            if not bool((torch.isfinite(s) & (s > 0)).all()):
                raise ValueError(f"the primitive scale must be finite and > 0 (m) in every row, got "
                                 f"{s.unique()[:5].tolist()}")
            lanes.append(self.pos_scale(self.config.scale_feature(s).expand(rel_pos.shape[0], 1)))
        p = torch.cat(lanes, dim=-1)
        h = self.trunk(torch.cat([features, self.pos_merge(p)], dim=-1))
        if self.config.dueling:
            adv = self.advantage(h)
            return self.value(h) + adv - adv.mean(dim=-1, keepdim=True)
        return self.out(h)


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
