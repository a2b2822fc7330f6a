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
    latency (ms) and the commanded primitive (drawn with its set): the recorder writes the typed
    record's fields as they are (``Recorder.step_record``)."""
    recorder.step_record(t_mono_s, record, latency_ms=latency_ms, primitive=primitive)
