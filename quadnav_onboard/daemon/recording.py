"""Where the daemon meets the flight recorder: a wrapper that never lets recording break a flight,
and the one place a step's typed record is handed over."""

from __future__ import annotations

from typing import Any

from quadnav_onboard.logs import get_logger
from quadnav_onboard.step import StepRecord

__all__ = ["SafeRecorder", "record_step"]

log = get_logger("quadnav.daemon")


class SafeRecorder:
    """Calls the flight recorder (:class:`~quadnav_onboard.record.protocol.Recorder`) but never
    lets it break the flight: missing, failing or None, a call returns None and the first failure
    of each method is logged."""

    def __init__(self, recorder: Any) -> None:
        self._rec = recorder
        self._failed: set[str] = set()

    def __getattr__(self, name: str) -> Any:
        target = getattr(self._rec, name, None) if self._rec is not None else None

        def call(*args: Any, **kwargs: Any) -> Any:
            if target is None:
                return None
            try:
                return target(*args, **kwargs)
            except Exception as exc:
                if name not in self._failed:
                    self._failed.add(name)
                    log.error("recorder_failed", method=name, error=f"{type(exc).__name__}: {exc}")
                return None

        return call


def record_step(
    recorder: SafeRecorder, t_mono_s: float, record: StepRecord, *, latency_ms: float, primitive: Any
) -> None:
    """Record one executed step (``record``, N = 1) decided at ``t_mono_s``, with the decision's
    latency (ms) and the commanded primitive (drawn with its set)."""
    r = record.as_dict(0)
    recorder.step(
        t_mono_s,
        step=r["step"],
        action=r["action"],
        q_values=record.q_values[0],
        rel_pos_body_m=record.rel_pos_body_m[0],
        moving_setpoint_world_m=record.moving_setpoint_world_m[0],
        pos_world_m=record.pos_world_m[0],
        reward=r["reward"],
        reward_terms={
            "d_prev_m": r["d_prev_m"],
            "d_now_m": r["d_now_m"],
            "deviated": r["deviated"],
            "collided": r["collided"],
        },
        progress_m=r["progress_m"],
        deviation_m=r["deviation_m"],
        latency_ms=latency_ms,
        shield_allowed=None if record.shield_allowed is None else record.shield_allowed[0],
        shield_clearance_m=None if record.shield_clearance_m is None else record.shield_clearance_m[0],
        primitive=primitive,
    )
