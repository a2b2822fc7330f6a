"""The self-contained HTML report: one file, plots inline as base64 PNG, no scripts, no network.

For each flight: the paper's row and why it stopped; where it went (top/side views over the
world); how well the vehicle tracked the setpoints and with what lag; what it saw (network input
at every decision, raw depth); what it chose (Q-values and actions); the mode/failsafe timeline;
latency histograms; events; metadata (config, model hash). Several flights: the paper's table
with success and collision-free rates and an overlay of all trajectories first.
"""

from __future__ import annotations

import base64
import html
import io
import math
from collections.abc import Sequence
from datetime import datetime, timezone
from pathlib import Path

import matplotlib.pyplot as plt
from matplotlib.figure import Figure

from quadnav_onboard.record.reader import FlightRecord
from quadnav_onboard.review import plots, plots_decisions
from quadnav_onboard.review.table import FlightRow, rates

__all__ = ["render_report", "write_report"]

_CSS = """
body { font-family: system-ui, -apple-system, "Segoe UI", sans-serif; margin: 24px auto; max-width: 1150px;
       color: #1d232b; background: #fff; line-height: 1.4; }
h1 { font-size: 26px; margin-bottom: 4px; } h2 { font-size: 20px; margin-top: 34px;
       border-bottom: 2px solid #dde3ea; padding-bottom: 4px; } h3 { font-size: 16px; margin-top: 22px; }
table { border-collapse: collapse; margin: 8px 0; font-size: 14px; }
th, td { border: 1px solid #d5dbe2; padding: 4px 10px; text-align: left; }
th { background: #eef2f6; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.row { font-size: 17px; }
.crash { color: #c62828; font-weight: bold; } .ok { color: #2e7d32; font-weight: bold; }
.warn { background: #fff4e5; border-left: 4px solid #f57c00; padding: 6px 10px; margin: 6px 0; }
img { max-width: 100%; display: block; margin: 6px 0 14px 0; }
pre { background: #f5f7f9; padding: 8px; overflow-x: auto; font-size: 12px; }
.muted { color: #5f6b7a; font-size: 13px; }
"""


def _png(fig: Figure) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _img(fig: Figure, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{_png(fig)}">'


def _e(x: object) -> str:
    return html.escape(str(x))


def _pct(x: float) -> str:
    return "–" if isinstance(x, float) and math.isnan(x) else f"{100 * x:.0f}%"


def _row_table(rows: Sequence[FlightRow]) -> str:
    head = (
        "<tr><th>world</th><th>record</th><th>navigation distance (m)</th><th>navigation time (s)</th>"
        "<th>crash</th><th>total reward</th><th>goal</th><th>stop reason</th></tr>"
    )
    body = []
    for r in rows:
        crash = '<span class="crash">Y</span>' if r.crashed else "N"
        goal = '<span class="ok">yes</span>' if r.reached_goal else "no"
        cut = "" if r.complete else ' <span class="crash">(record cut off)</span>'
        body.append(
            f"<tr><td>{_e(r.world)}</td><td>{_e(r.record)}</td>"
            f"<td class=num>{r.navigation_distance_m:.2f}</td><td class=num>{r.navigation_time_s:.1f}</td>"
            f"<td>{crash}</td><td class=num>{r.total_reward:.2f}</td>"
            f"<td>{goal}</td><td>{_e(r.stop_reason)}{cut}</td></tr>"
        )
    return f"<table class=row>{head}{''.join(body)}</table>"


def _events_table(rec: FlightRecord) -> str:
    if not rec.events:
        return "<p class=muted>No events recorded.</p>"
    t0 = plots.t_zero(rec)
    levels = {0: "?", 1: "debug", 2: "info", 3: "warning", 4: "error", 5: "fatal"}
    rows = "".join(
        f"<tr><td class=num>{float(e['t_mono_s']) - t0:.2f}</td>"
        f"<td>{_e(levels.get(int(e.get('level', 2)), '?'))}</td><td>{_e(e.get('kind', ''))}</td>"
        f"<td>{_e(e.get('message', ''))}</td>"
        f"<td>{_e(e.get('fields') or '')}</td></tr>"
        for e in rec.events[:500]
    )
    more = (
        f"<p class=muted>{len(rec.events) - 500} more events not shown.</p>" if len(rec.events) > 500 else ""
    )
    return (
        "<table><tr><th>t (s)</th><th>level</th><th>kind</th><th>message</th><th>fields</th></tr>"
        f"{rows}</table>{more}"
    )


def _metadata(rec: FlightRecord) -> str:
    parts = []
    for name, data in rec.metadata.items():
        short = {k: v for k, v in data.items() if "\n" not in v and len(v) < 200}
        long = {k: v for k, v in data.items() if k not in short}
        rows = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in short.items())
        parts.append(f"<h3>metadata: {_e(name)}</h3><table>{rows}</table>")
        for k, v in long.items():
            parts.append(f"<details><summary>{_e(name)}.{_e(k)}</summary><pre>{_e(v)}</pre></details>")
    return "".join(parts)


def _clock(rec: FlightRecord) -> str:
    """When the flight's first decision was, in UTC, and how PX4's ULog lines up with it."""
    if rec.format_version < 2:
        return "record format 1: monotonic times only"
    t0_ns = round(plots.t_zero(rec) * 1e9) + rec.unix_minus_mono_ns
    start = datetime.fromtimestamp(t0_ns / 1e9, tz=timezone.utc).strftime("%Y-%m-%d %H:%M:%S.%f")[:-3]
    px4 = (
        f"PX4 ULog time + {rec.px4_time[-1]['unix_minus_px4_boot_us']} µs = UTC"
        if rec.px4_time
        else "no PX4 clock recorded"
    )
    return f"time 0 = {start} UTC · {px4}"


def _flight_section(rec: FlightRecord, row: FlightRow, warnings: Sequence[str]) -> str:
    out = [f"<h2>Flight {_e(rec.name)}</h2>", _row_table([row])]
    stop = rec.stop or {}
    dropped = {k: v for k, v in (stop.get("dropped") or {}).items() if v}
    out.append(
        f"<p>Stopped because: <b>{_e(row.stop_reason)}</b>{' (' + _e(row.detail) + ')' if row.detail else ''}"
        f" · {row.steps} decisions · "
        f"record {'complete' if rec.complete else 'CUT OFF: ' + _e(rec.problem or '')} · "
        f"dropped: {_e(dropped or 'none')} · model {_e(rec.info.get('model_sha256', '?')[:12])}"
        f" · {_e(_clock(rec))}</p>"
    )
    out.extend(f'<div class="warn">{_e(w)}</div>' for w in warnings)
    out.append("<h3>Where it went</h3>")
    out.append(_img(plots.fig_trajectory(rec), "top and side trajectory views"))
    fig, lag = plots.fig_tracking(rec)
    out.append(f"<h3>Setpoint tracking (lag ≈ {lag:.2f} s)</h3>")
    out.append(_img(fig, "setpoint vs flown position over time"))
    out.append("<h3>What it chose</h3>")
    out.append(_img(plots_decisions.fig_decisions(rec), "Q-values and actions per decision"))
    out.append("<h3>What it saw</h3>")
    if rec.network_inputs:
        out.append(_img(plots_decisions.fig_inputs(rec), "network depth input at each decision"))
    if rec.depth:
        out.append(_img(plots_decisions.fig_depth(rec), "raw depth frames"))
    if not rec.network_inputs and not rec.depth:
        out.append("<p class=muted>No images recorded.</p>")
    out.append("<h3>Modes, failsafes and events</h3>")
    out.append(_img(plots_decisions.fig_modes(rec), "mode and event timeline"))
    out.append(_events_table(rec))
    out.append("<h3>Latency</h3>")
    out.append(_img(plots_decisions.fig_latency(rec), "latency histograms"))
    if stop.get("summary"):
        out.append(f"<details><summary>daemon summary</summary><pre>{_e(stop['summary'])}</pre></details>")
    out.append(_metadata(rec))
    return "\n".join(out)


def render_report(
    records: Sequence[FlightRecord], rows: Sequence[FlightRow], warnings: Sequence[Sequence[str]]
) -> str:
    """The report as one HTML string."""
    title = records[0].name if len(records) == 1 else f"{len(records)} flights"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>quadnav review — {_e(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>quadnav flight review — {_e(title)}</h1>",
        "<p class=muted>Positions: world frame (x forward, y left, z up), metres. "
        "Times: seconds since the first decision.</p>",
    ]
    if len(records) > 1:
        r = rates(rows)
        parts.append("<h2>Results across trials</h2>")
        parts.append(_row_table(rows))
        parts.append(
            f"<p class=row>{r['trials']} trials · success {_pct(r['success_rate'])} · collision-free "
            f"{_pct(r['collision_free_rate'])} · success among collision-free "
            f"{_pct(r['success_among_safe'])}</p>"
        )
        parts.append(_img(plots.fig_overlay(records), "all trajectories, top view"))
    for rec, row, ws in zip(records, rows, warnings, strict=True):
        parts.append(_flight_section(rec, row, ws))
    parts.append("</body></html>")
    return "\n".join(parts)


def write_report(
    out: str | Path,
    records: Sequence[FlightRecord],
    rows: Sequence[FlightRow],
    warnings: Sequence[Sequence[str]],
) -> Path:
    """Write the report to ``out`` (folders created); returns the path."""
    out = Path(out)
    text = render_report(records, rows, warnings)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    return out
