"""Thread counts of torch and numba, so a learner and an env in one process share the cores.

Both libraries default to one thread per core. In one process the env's parallel numba kernels
(rendering, collision) and torch's OpenMP pool then run at the same time and fight over the same
cores; on a 2-core machine Stable-Baselines3's DQN on :class:`sim_harness.env.QuadNavEnv` ran
~4x slower with the defaults than with one thread each (docs/training.md, "Threads").
"""

from __future__ import annotations

import dataclasses

__all__ = ["ThreadCounts", "limit_threads"]



@dataclasses.dataclass(frozen=True)
class ThreadCounts:
    """Thread counts in force (after :func:`limit_threads`)."""

    torch: int
    """torch.get_num_threads()."""
    numba: int
    """numba.get_num_threads() of the calling thread."""


def limit_threads(torch_threads: int = 1, numba_threads: int = 1) -> ThreadCounts:
    """Set torch's intra-op threads and numba's threads (clipped to numba's pool; 0 leaves it).

    Returns the counts in force. One of each is right for one env and one small network per
    process (a sweep trial, a Stable-Baselines3 run): the work per call is too small to split."""
    import numba
    import torch

    # numba first, then torch: numba starting its OpenMP pool (its first parallel kernel, or
    # set_num_threads) sets OpenMP's thread count, which is torch's too, back to numba's pool size,
    # so a torch count set before that does not last (measured: torch 1 -> 2)
    if numba_threads >= 1:
        numba.set_num_threads(min(numba_threads, numba.config.NUMBA_NUM_THREADS))
    if torch_threads >= 1:
        torch.set_num_threads(torch_threads)
    return ThreadCounts(torch=torch.get_num_threads(), numba=numba.get_num_threads())
