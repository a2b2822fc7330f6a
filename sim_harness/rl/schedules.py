"""The paper's episode-indexed schedules: linear from start to end over the first fraction, then flat.

ε decays 1.0 -> 0.1 and γ grows 0.01 -> 0.99 linearly over the first 80 % of the episodes and stay
at their end values for the last 20 % (Camci & Kayacan, Sec. IV-A).
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ["LinearSchedule", "linear_schedule", "linear_tail"]


def linear_schedule(start: float, end: float, episode: float, total_episodes: int, fraction: float) -> float:
    """Value at ``episode`` (0-based) of a ramp reaching ``end`` at ``fraction * total_episodes``."""
    if total_episodes < 1:
        raise ValueError(f"total_episodes must be >= 1, got {total_episodes}")
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    ramp = fraction * total_episodes
    p = min(max(float(episode) / ramp, 0.0), 1.0)
    return float(start + (end - start) * p)


def linear_tail(start: float, end: float, episode: float, total_episodes: int, fraction: float) -> float:
    """The other half of :func:`linear_schedule`: ``start`` through the first ``fraction`` of the
    episodes, then linear to ``end`` at the last one (a step size that decays once ε and γ are
    flat)."""
    linear_schedule(start, end, 0, total_episodes, fraction)  # the same argument checks
    ramp = fraction * total_episodes
    p = min(max((float(episode) - ramp) / max(total_episodes - ramp, 1.0), 0.0), 1.0)
    return float(start + (end - start) * p)


@dataclass(frozen=True)
class LinearSchedule:
    """A linear ramp over episodes: ``start`` at episode 0, ``end`` from ``fraction * total`` on."""

    start: float
    """Value at episode 0."""
    end: float
    """Value from the end of the ramp on."""
    total_episodes: int
    """Episodes in the whole run."""
    fraction: float = 0.8
    """Fraction of the run over which the value ramps (the paper: 0.8)."""

    def __call__(self, episode: float) -> float:
        return linear_schedule(self.start, self.end, episode, self.total_episodes, self.fraction)
