"""The flight summary: the paper's row, why the flight stopped, and its timing figures."""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

from quadnav_onboard.logs import get_logger

if TYPE_CHECKING:
    from quadnav_onboard.daemon.stats import RunStats
    from quadnav_onboard.daemon.supervisor import StopReason

__all__ = ["FlightSummary"]

log = get_logger("quadnav.daemon")


def _r(x: float, nd: int = 3) -> float | None:
    return None if x is None or not math.isfinite(x) else round(float(x), nd)


@dataclass(frozen=True)
class FlightSummary:
    """One flight: the paper's row (distance, time, crash, reward), why it stopped, and timings."""

    stop_reason: str
    """:class:`StopReason` value."""
    detail: str
    """Human-readable detail of the stop."""
    exit_code: int
    """Process exit code (see :class:`ExitCode`)."""
    steps: int
    """Primitives executed."""
    navigation_distance_m: float
    """Progress along the rough path (m) at the end: the paper's navigation distance."""
    flight_time_s: float
    """Mission time (s) from the first decision to the stop."""
    crashed: bool
    """A collision was reported."""
    total_reward: float
    """Sum of the per-step rewards, computed exactly as in training."""
    decision_latency_ms: dict[str, float | None]
    """Newest frame taken -> first setpoint of the new primitive sent: n, p50, p99, max (ms)."""
    inference_ms: dict[str, float | None]
    """The step's DQN work from the step boundary (the head; plus any wait for, or run of, the
    frame's preparation): n, p50, p99, max (ms)."""
    frame_age_ms: dict[str, float | None]
    """Age of the depth frame each decision used, at the step boundary: n, p50, p99, max (ms)."""
    decision_paths: dict[str, int]
    """How each decision got its prepared frame: ready at the step boundary, awaited, or prepared
    in the step: {"prepared": n, "waited": n, "full": n}."""
    depth_frames: dict[str, int]
    """Depth frames received, fully prepared, and only checked (``depth.prepare_within_s``)."""
    setpoint_interval_ms: dict[str, float | None]
    """Interval between setpoints sent: n, p50, p99, max (ms)."""
    hold_reaction_ms: float | None
    """Stale-input threshold -> hold command (ms), when the flight stopped for stale input."""
    vision_forwards: dict[str, int]
    """Mocap poses forwarded to PX4's estimator: {"sent": n, "failed": n}."""
    model_sha256: str
    """SHA-256 of the checkpoint flown."""
    startup: dict[str, Any] = field(default_factory=dict)
    """Start -> READY (s), preflight's warm-up (s), the kernels compiled after arming (none
    expected), the ground frame, the odometry stream and its stale limit, PX4's parameters and
    the OFFBOARD tries: {"ready_s": s, "warmup_s": s, "kernels_compiled_in_flight": {name: n},
    "ground": {...}, "odometry": {...}, "px4_parameters": {...}, "offboard_start_attempts": n}."""
    landing: dict[str, Any] = field(default_factory=dict)
    """After a land: {"landed": bool, "disarm": "auto" (PX4's COM_DISARM_LAND) | "commanded" |
    "still_armed", "waited_s": s}; empty when the ladder did not land."""

    @classmethod
    def build(
        cls,
        *,
        reason: StopReason,
        detail: str,
        steps: int,
        navigation_distance_m: float,
        flight_time_s: float,
        crashed: bool,
        total_reward: float,
        stats: RunStats,
        model_sha256: str,
    ) -> FlightSummary:
        def lat(s: Any) -> dict[str, float | None]:
            return {k: (int(v) if k == "n" else _r(v)) for k, v in s.summary().items()}

        hold = stats.hold_reaction_s
        return cls(
            stop_reason=reason.value,
            detail=detail,
            exit_code=int(reason.exit_code),
            steps=int(steps),
            navigation_distance_m=_r(navigation_distance_m) or 0.0,
            flight_time_s=_r(flight_time_s) or 0.0,
            crashed=bool(crashed),
            total_reward=_r(total_reward, 4) or 0.0,
            decision_latency_ms=lat(stats.decision_latency),
            inference_ms=lat(stats.inference),
            frame_age_ms=lat(stats.frame_age),
            decision_paths=dict(stats.decision_paths),
            depth_frames={
                "received": stats.depth_frames,
                "prepared": stats.depth_frames_prepared,
                "checked": stats.depth_frames_checked,
            },
            setpoint_interval_ms=lat(stats.setpoint_interval),
            hold_reaction_ms=None if hold is None else _r(hold * 1e3),
            vision_forwards={"sent": stats.vision_forwards, "failed": stats.vision_forward_failures},
            model_sha256=model_sha256,
            startup={
                "ready_s": None if stats.ready_s is None else _r(stats.ready_s, 3),
                "warmup_s": None if stats.warmup_s is None else _r(stats.warmup_s, 3),
                "kernels_compiled_in_flight": dict(stats.kernels_compiled_in_flight),
                "ground": dict(stats.ground),
                "odometry": dict(stats.odometry),
                "px4_parameters": dict(stats.px4_parameters),
                "offboard_start_attempts": stats.offboard_start_attempts,
            },
            landing=dict(stats.landing),
        )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def paper_row(self) -> str:
        """The paper's table row, plus the stop reason."""
        return (
            f"navigation distance {self.navigation_distance_m:.2f} m | time {self.flight_time_s:.1f} s | "
            f"crash {'yes' if self.crashed else 'no'} | total reward {self.total_reward:.3f} | "
            f"stop: {self.stop_reason} ({self.detail})"
        )

    def latency_lines(self) -> list[str]:
        def fmt(name: str, d: dict[str, float | None]) -> str:
            return f"{name}: n={d['n']} p50={d['p50_ms']} ms p99={d['p99_ms']} ms max={d['max_ms']} ms"

        lines = [
            fmt("decision latency (frame -> first setpoint)", self.decision_latency_ms),
            fmt("DQN at the step (head; + preprocess and depth lane if not prepared)", self.inference_ms),
            fmt("frame age at the step (sensor latency)", self.frame_age_ms),
            "decisions: {prepared} on a frame prepared on arrival, {waited} waited for its "
            "preparation, {full} prepared in the step".format(**self.decision_paths),
            "depth frames: {received} received, {prepared} prepared, {checked} only checked".format(
                **self.depth_frames
            ),
            fmt("setpoint interval", self.setpoint_interval_ms),
        ]
        if self.hold_reaction_ms is not None:
            lines.append(f"stale input -> hold: {self.hold_reaction_ms} ms")
        st = self.startup
        if st.get("ready_s") is not None:
            lines.append(f"start -> ready: {st['ready_s']} s (warm-up {st['warmup_s']} s)")
        if st.get("kernels_compiled_in_flight"):
            lines.append(f"kernels compiled after arming: {st['kernels_compiled_in_flight']}")
        if self.landing:
            d = self.landing
            lines.append(f"landing: landed {d.get('landed')}, disarm {d.get('disarm')} "
                         f"(waited {d.get('waited_s', 0)} s)")
        if self.vision_forwards["failed"]:
            v = self.vision_forwards
            lines.append(f"vision forwards to PX4: {v['sent']} sent, {v['failed']} failed")
        return lines
