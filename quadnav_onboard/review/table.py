"""The paper's results row and table (Camci & Kayacan, Tables I-II) from flight records.

One flight gives one row: navigation distance (m), navigation time (s), crash (Y/N), total
reward, plus the stop reason. The row is taken from the summary the daemon passed to
``FlightRecorder.close(summary=...)`` (so it equals what the daemon printed), under the keys in
:data:`SUMMARY_KEYS`; a key missing there (or a record cut off before the summary was written) is
computed from the recorded decisions instead, and the row says so (``source``).

Several rows give the table, grouped by world, with the paper's rates: success (goal reached)
and collision-free flights.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from quadnav_onboard.record.reader import FlightRecord

__all__ = [
    "SUMMARY_ALIASES",
    "SUMMARY_KEYS",
    "FlightRow",
    "format_row",
    "format_table",
    "numbers_from_steps",
    "rates",
    "row_from_record",
    "row_from_summary",
    "summary_value",
    "world_name",
]

SUMMARY_KEYS = (
    "navigation_distance_m",
    "navigation_time_s",
    "crashed",
    "total_reward",
    "reached_goal",
    "steps",
)
"""Keys of the flight summary (``close(summary=...)``) that make the paper's row:
navigation distance (m, progress along the rough path), navigation time (s, from the first
decision to the end of the last primitive), crashed (bool), total reward (sum over steps),
reached_goal (bool; default: stop reason ``goal_reached``), steps (decisions taken).
Aliases: :data:`SUMMARY_ALIASES`."""

SUMMARY_ALIASES: dict[str, tuple[str, ...]] = {"navigation_time_s": ("flight_time_s",)}
"""Other names accepted for a summary key (the daemon's FlightSummary says ``flight_time_s``)."""


def summary_value(summary: Mapping[str, Any], key: str) -> Any:
    """``summary[key]`` or its first alias present; None when absent."""
    for k in (key, *SUMMARY_ALIASES.get(key, ())):
        if summary.get(k) is not None:
            return summary[k]
    return None


_CRASH_REASONS = ("crash", "collision")
_GOAL_REASONS = ("goal_reached", "goal")


@dataclass(frozen=True)
class FlightRow:
    """One flight in the paper's table."""

    record: str
    """Record file name."""
    world: str
    """World / environment name from the record's metadata ("" when unknown)."""
    navigation_distance_m: float
    navigation_time_s: float
    crashed: bool
    total_reward: float
    reached_goal: bool
    steps: int
    stop_reason: str
    """Why the flight stopped ("(cut off)" when the record ends without one)."""
    detail: str
    """The daemon's human-readable detail of the stop ("" when none)."""
    complete: bool
    """The record was closed properly (False: cut off, e.g. SIGKILL)."""
    source: str
    """"summary" (the daemon's numbers), "steps" (computed from decisions) or "summary+steps"."""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def numbers_from_steps(rec: FlightRecord) -> dict[str, Any]:
    """The row's numbers computed from the recorded decisions (used when the summary lacks them)."""
    n = len(rec.steps)
    if n == 0:
        return {
            "navigation_distance_m": 0.0,
            "navigation_time_s": 0.0,
            "total_reward": 0.0,
            "steps": 0,
        }
    progress = rec.step_array("progress_m")
    reward = rec.step_array("reward")
    t = rec.step_t_s
    if n > 1:  # the last decision's primitive runs one step interval (the stop may come later: landing)
        t_end = float(t[-1]) + float(np.median(np.diff(t)))
    elif rec.stop is not None:
        t_end = float(rec.stop["t_mono_s"])
    else:
        t_end = float(t[-1])
    return {
        "navigation_distance_m": float(np.nanmax(progress)) if np.any(np.isfinite(progress)) else 0.0,
        "navigation_time_s": max(0.0, t_end - float(t[0])),
        "total_reward": float(np.nansum(reward)),
        "steps": n,
    }


def _reason_flags(reason: str) -> tuple[bool, bool]:
    r = reason.lower()
    return any(k in r for k in _CRASH_REASONS), any(r.startswith(k) for k in _GOAL_REASONS)


def row_from_summary(
    summary: Mapping[str, Any], *, stop_reason: str, record: str = "", world: str = ""
) -> FlightRow:
    """The row from a daemon summary alone (what the daemon prints at the end of a flight)."""
    crashed, reached = _reason_flags(stop_reason)
    defaults: dict[str, Any] = {"crashed": crashed, "reached_goal": reached}

    def get(key: str) -> Any:
        v = summary_value(summary, key)
        return defaults.get(key, 0) if v is None else v

    return FlightRow(
        record=record,
        world=world,
        navigation_distance_m=float(get("navigation_distance_m")),
        navigation_time_s=float(get("navigation_time_s")),
        crashed=bool(get("crashed")),
        total_reward=float(get("total_reward")),
        reached_goal=bool(get("reached_goal")),
        steps=int(get("steps")),
        stop_reason=stop_reason,
        detail=str(summary.get("detail") or ""),
        complete=True,
        source="summary",
    )


def row_from_record(rec: FlightRecord) -> FlightRow:
    """The paper's row for one record: the daemon's summary where given, the decisions otherwise."""
    summary: Mapping[str, Any] = rec.stop.get("summary", {}) if rec.stop else {}
    reason = str(rec.stop.get("stop_reason", "")) if rec.stop else "(cut off)"
    computed = numbers_from_steps(rec)
    crashed, reached = _reason_flags(reason)
    computed.update(crashed=crashed, reached_goal=reached)
    values: dict[str, Any] = {}
    used = set()
    for key in SUMMARY_KEYS:
        v = summary_value(summary, key)
        if v is not None:
            values[key] = v
            used.add("summary")
        else:
            values[key] = computed[key]
            if key not in ("crashed", "reached_goal"):  # these follow from the stop reason
                used.add("steps")
    return FlightRow(
        record=rec.name,
        world=world_name(rec.info),
        navigation_distance_m=float(values["navigation_distance_m"]),
        navigation_time_s=float(values["navigation_time_s"]),
        crashed=bool(values["crashed"]),
        total_reward=float(values["total_reward"]),
        reached_goal=bool(values["reached_goal"]),
        steps=int(values["steps"]),
        stop_reason=reason,
        detail=str(summary.get("detail") or ""),
        complete=rec.complete,
        source="+".join(s for s in ("summary", "steps") if s in used),
    )


def world_name(info: Mapping[str, str]) -> str:
    """The world's name from record metadata: ``world_name``, the ``name`` in ``world_yaml``, else
    ``world`` (a world file path: the name inside it when readable, else the file's stem)."""
    if info.get("world_name"):
        return info["world_name"]
    ref = info.get("world") or ""
    text = info.get("world_yaml")
    if not text and ref.endswith((".yaml", ".yml")):
        with contextlib.suppress(OSError):
            text = Path(ref).read_text(encoding="utf-8")
    if text:
        with contextlib.suppress(yaml.YAMLError):
            data = yaml.safe_load(text)
            if isinstance(data, dict) and isinstance(data.get("name"), str):
                return data["name"]
    return Path(ref).stem if ref.endswith((".yaml", ".yml")) else ref


def format_row(row: FlightRow) -> str:
    """One line, the paper's columns and the stop, exactly as the daemon prints it at the end::

    navigation distance 60.00 m | time 57.0 s | crash no | total reward 12.150 | stop: goal_reached (...)
    """
    detail = f" ({row.detail})" if row.detail else ""
    return (
        f"navigation distance {row.navigation_distance_m:.2f} m | time {row.navigation_time_s:.1f} s | "
        f"crash {'yes' if row.crashed else 'no'} | total reward {row.total_reward:.3f} | "
        f"stop: {row.stop_reason}{detail}"
    )


def rates(rows: Sequence[FlightRow]) -> dict[str, float]:
    """Success rate (goal reached), collision-free rate, and success among collision-free flights."""
    n = len(rows)
    if n == 0:
        return {
            "trials": 0,
            "success_rate": math.nan,
            "collision_free_rate": math.nan,
            "success_among_safe": math.nan,
        }
    safe = [r for r in rows if not r.crashed]
    return {
        "trials": n,
        "success_rate": sum(r.reached_goal for r in rows) / n,
        "collision_free_rate": len(safe) / n,
        "success_among_safe": (sum(r.reached_goal for r in safe) / len(safe)) if safe else math.nan,
    }


def _pct(x: float) -> str:
    return "  -" if math.isnan(x) else f"{100 * x:3.0f}%"


def format_table(rows: Sequence[FlightRow]) -> str:
    """The paper's table: rows grouped by world, each group's rates, then the overall rates."""
    head = f"{'world':<22} {'record':<28} {'dist (m)':>9} {'time (s)':>9} {'crash':>5} {'reward':>8}  stop"
    lines = [head, "-" * len(head)]
    groups: dict[str, list[FlightRow]] = {}
    for r in rows:
        groups.setdefault(r.world or "(unknown world)", []).append(r)
    for world, group in groups.items():
        for r in group:
            flag = "" if r.complete else "  [cut off]"
            lines.append(
                f"{world[:22]:<22} {r.record[:28]:<28} {r.navigation_distance_m:9.2f} "
                f"{r.navigation_time_s:9.1f} {'Y' if r.crashed else 'N':>5} {r.total_reward:8.2f}  "
                f"{r.stop_reason}{flag}"
            )
        if len(groups) > 1:
            g = rates(group)
            lines.append(
                f"{'':<22} {'  ' + world[:20] + ' rates':<28} success {_pct(g['success_rate'])}  "
                f"collision-free {_pct(g['collision_free_rate'])}"
            )
    total = rates(rows)
    lines.append("-" * len(head))
    lines.append(
        f"{total['trials']} trials: success {_pct(total['success_rate'])}, "
        f"collision-free {_pct(total['collision_free_rate'])}, "
        f"success among collision-free {_pct(total['success_among_safe'])}"
    )
    return "\n".join(lines)
