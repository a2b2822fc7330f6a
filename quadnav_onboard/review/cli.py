"""``quadnav-review``: what a flight saw, chose, where it went and why it stopped.

    quadnav-review RECORD.mcap                 # the paper's row and the stop reason
    quadnav-review records/ a.mcap b.mcap      # the paper's table with success/collision-free rates
    quadnav-review RECORD.mcap --json          # the same as JSON, for scripts
    quadnav-review RECORD.mcap --html out.html # a self-contained report (plots inline)
    quadnav-review RECORD.mcap --html out.html --world arena.yaml  # draw this world if none recorded

A folder argument stands for the ``*.mcap`` files in it. Exit status: 0 all records read,
1 a record could not be read (one line each on stderr, the others are still reviewed), 2 usage.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Any

from quadnav_onboard.record.reader import FlightRecord, RecordError, read_record
from quadnav_onboard.record.schemas import to_jsonable
from quadnav_onboard.review.table import (
    FlightRow,
    format_row,
    format_table,
    numbers_from_steps,
    rates,
    row_from_record,
    summary_value,
)

__all__ = ["build_parser", "consistency_warnings", "main"]

_TOL = {"navigation_distance_m": 0.05, "navigation_time_s": 1.5, "total_reward": 0.05}


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadnav-review",
        description="Review quadnav flight records (MCAP): the paper's row/table, JSON, or an HTML report.",
    )
    p.add_argument("records", nargs="+", metavar="RECORD", help="record file(s) (.mcap) or folder(s) of them")
    p.add_argument("--json", action="store_true", help="print rows and rates as JSON")
    p.add_argument("--html", metavar="OUT.html", help="write a self-contained HTML report")
    p.add_argument("--quiet", "-q", action="store_true", help="no warnings, only the row/table")
    p.add_argument(
        "--world",
        metavar="WORLD.yaml",
        help="world file to draw in the report when a record carries none (e.g. a real flight's arena)",
    )
    return p


def _world_yaml(path: str) -> str:
    """The text of a world file, checked to be a YAML mapping; RecordError (one line) otherwise."""
    from quadnav_onboard.config import ConfigError, load_yaml

    try:
        data = load_yaml(path)
    except ConfigError as exc:
        raise RecordError(str(exc)) from None
    if not isinstance(data, dict):
        raise RecordError(f"{path}: a world file must be a YAML mapping")
    return Path(path).read_text(encoding="utf-8")


def _expand(args: list[str]) -> list[Path]:
    out: list[Path] = []
    for a in args:
        p = Path(a)
        if p.is_dir():
            found = sorted(p.glob("*.mcap"))
            out.extend(found if found else [p])  # an empty folder is reported as an error
        else:
            out.append(p)
    return out


def consistency_warnings(rec: FlightRecord, row: FlightRow) -> list[str]:
    """Warnings a reviewer must see: cut-off records, dropped data, summary vs decisions mismatch."""
    warns: list[str] = []
    if not rec.complete:
        warns.append(f"record is incomplete: {rec.problem or 'no footer'}; read up to the last whole chunk")
    if rec.stop is not None:
        dropped = {k: v for k, v in (rec.stop.get("dropped") or {}).items() if v}
        if dropped:
            warns.append(f"recorder dropped messages: {dropped}")
        summary = rec.stop.get("summary") or {}
        if rec.steps:
            computed = numbers_from_steps(rec)
            for key, tol in _TOL.items():
                given = summary_value(summary, key)
                if given is not None:
                    a, b = float(given), float(computed[key])
                    if math.isfinite(a) and abs(a - b) > tol:
                        warns.append(f"summary {key}={a:.2f} differs from the recorded decisions ({b:.2f})")
    return warns


def _row_json(rec: FlightRecord, row: FlightRow, warns: list[str]) -> dict[str, Any]:
    d = row.to_dict()
    d["path"] = str(rec.path)
    d["problem"] = rec.problem
    d["dropped"] = (rec.stop or {}).get("dropped", {})
    d["warnings"] = warns
    return d


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    world_text = None
    if args.world:
        try:
            world_text = _world_yaml(args.world)
        except RecordError as exc:
            print(f"quadnav-review: --world: {exc}", file=sys.stderr)
            return 2
    records: list[FlightRecord] = []
    rows: list[FlightRow] = []
    warnings: list[list[str]] = []
    failed = 0
    for path in _expand(args.records):
        if path.is_dir():
            print(f"quadnav-review: {path}: folder holds no .mcap records", file=sys.stderr)
            failed += 1
            continue
        try:
            rec = read_record(path, load_depth=bool(args.html))
        except RecordError as exc:
            print(f"quadnav-review: {exc}", file=sys.stderr)
            failed += 1
            continue
        except Exception as exc:  # a record we did not foresee: still one line, never a traceback
            print(f"quadnav-review: {path}: unreadable record: {type(exc).__name__}: {exc}", file=sys.stderr)
            failed += 1
            continue
        if world_text is not None and "world_yaml" not in rec.info:
            rec.metadata.setdefault("quadnav", {})["world_yaml"] = world_text
        row = row_from_record(rec)
        records.append(rec)
        rows.append(row)
        warnings.append(consistency_warnings(rec, row))

    if rows:
        if args.json:
            items = [_row_json(r, w, ws) for r, w, ws in zip(records, rows, warnings, strict=True)]
            out: dict[str, Any] = items[0] if len(items) == 1 else {"rows": items, "rates": rates(rows)}
            print(json.dumps(to_jsonable(out), indent=2))
        elif len(rows) == 1:
            rec, row = records[0], rows[0]
            world = f"world {row.world} · " if row.world else ""
            print(f"{rec.name}: {world}{row.steps} decisions · {'complete' if rec.complete else 'CUT OFF'}")
            print(format_row(row))
        else:
            print(format_table(rows))
        if not args.quiet and not args.json:
            for rec, ws in zip(records, warnings, strict=True):
                for w in ws:
                    print(f"warning: {rec.name}: {w}", file=sys.stderr)
        if args.html:
            from quadnav_onboard.review.report import write_report

            try:
                out_path = write_report(args.html, records, rows, warnings)
            except OSError as exc:
                print(
                    f"quadnav-review: {args.html}: cannot write report: {exc.strerror or exc}",
                    file=sys.stderr,
                )
                return 1
            if not args.json:
                print(f"report: {out_path}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
