"""numba settings shared by every compiled kernel (the depth safety filter's, the sim harness's
render and collision kernels), and a census of what is compiled.

Nothing may compile after arming: a kernel that compiles in flight holds its thread for hundreds
of milliseconds (and, compiling, the GIL). The daemon warms its kernels in preflight and compares
:func:`signature_counts` at arming with the counts at the end of the flight; any new signature is
reported as compiled in flight.
"""

from __future__ import annotations

import sys

import numba
import numpy as np
from numba.core.dispatcher import Dispatcher
from numpy.typing import ArrayLike, DTypeLike

__all__ = ["CAN_CACHE", "compiled_since", "kernel_array", "kernels", "signature_counts"]

_PACKAGES = ("quadnav_onboard.", "sim_harness.")


def kernel_array(x: ArrayLike, dtype: DTypeLike) -> np.ndarray:
    """``x`` as a C-contiguous, writeable array of ``dtype`` (copied only when it is not one).

    numba compiles one signature per dtype, layout *and* writeability: a read-only view passed
    where a writeable array was warmed up compiles a second version, in flight. Every kernel
    argument goes through here, so what a caller hands in never changes the signature."""
    return np.require(x, dtype=dtype, requirements=("C", "W"))


def _probe() -> None:  # pragma: no cover - only ever decorated, never called
    """A function to ask numba whether it can cache the kernels of this package."""


def _can_cache() -> bool:
    """Whether numba has a writable cache location for this package: its ``__pycache__``,
    ``NUMBA_CACHE_DIR`` or the user's cache directory. A read-only install run by a user without
    a writable home has none; the kernels then compile once per process instead of failing."""
    try:
        numba.njit(cache=True)(_probe)
    except RuntimeError:
        return False
    return True


CAN_CACHE: bool = _can_cache()
"""Compile kernels with ``cache=True`` (False: compile in every process)."""


def kernels() -> dict[str, Dispatcher]:
    """Every numba kernel of this project's modules imported so far, by ``module.name``."""
    found: dict[str, Dispatcher] = {}
    for mod_name, module in list(sys.modules.items()):
        if module is None or not mod_name.startswith(_PACKAGES):
            continue
        for name, obj in list(vars(module).items()):
            if isinstance(obj, Dispatcher) and getattr(obj, "__module__", mod_name) == mod_name:
                found[f"{mod_name}.{name}"] = obj
    return found


def signature_counts() -> dict[str, int]:
    """How many compiled signatures each kernel has now (compiled or loaded from cache)."""
    return {name: len(k.signatures) for name, k in kernels().items()}


def compiled_since(before: dict[str, int]) -> dict[str, list[str]]:
    """Kernels with signatures added since ``before`` (a :func:`signature_counts`): the new
    signatures, as numba writes them (argument types)."""
    out: dict[str, list[str]] = {}
    for name, k in kernels().items():
        sigs = list(k.signatures)
        if len(sigs) > before.get(name, 0):
            out[name] = [str(sig) for sig in sigs[before.get(name, 0):]]
    return out
