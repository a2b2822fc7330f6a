"""scripts/rule_vs_alone.py: the selection rule's score against the goals flown alone."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "rule_vs_alone.py"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True)


def _select(path: Path, scores: dict[str, int]) -> str:
    path.write_text(json.dumps({"scores": [{"model": m, "score": s} for m, s in scores.items()]}))
    return str(path)


def _alone(path: Path, model: str, goals: int, flights: int = 10, enabled: bool = False) -> str:
    rows = [{"outcome": "goal" if i < goals else "crash"} for i in range(flights)]
    path.write_text(json.dumps({"model": model, "shield": {"enabled": enabled}, "rows": rows}))
    return str(path)


def test_pairs_by_model_path_and_ranks_ties_by_their_mean(tmp_path: Path) -> None:
    rule = {"a.pt": 290, "b.pt": 288, "c.pt": 288, "d.pt": 280, "bundled.pt": 292}
    sel = _select(tmp_path / "s.json", rule)
    alone = [_alone(tmp_path / f"{m}.json", f"{m}.pt", g) for m, g in
             [("a", 9), ("b", 7), ("c", 8), ("d", 2), ("e", 10)]]
    out = tmp_path / "out.json"
    done = run("--select", sel, "--alone", *alone, "--json", str(out))
    assert done.returncode == 0, done.stderr
    r = json.loads(out.read_text())
    assert [(p["model"], p["rule"], p["alone_goals"]) for p in r["pairs"]] == [
        ("a.pt", 290, 9), ("b.pt", 288, 7), ("c.pt", 288, 8), ("d.pt", 280, 2)]
    assert (r["scored_only"], r["flown_only"]) == (1, 1)
    # rule ranks 4, 2.5, 2.5, 1 against alone ranks 4, 2, 3, 1: Pearson's r on the ranks
    assert abs(r["spearman"] - 0.9486832980505138) < 1e-12
    assert "4 checkpoints" in done.stdout and "+0.95" in done.stdout


def test_an_order_reversed_gives_minus_one(tmp_path: Path) -> None:
    sel = _select(tmp_path / "s.json", {"a.pt": 1, "b.pt": 2, "c.pt": 3})
    alone = [_alone(tmp_path / f"{m}.json", f"{m}.pt", g) for m, g in [("a", 9), ("b", 5), ("c", 1)]]
    out = tmp_path / "out.json"
    assert run("--select", sel, "--alone", *alone, "--json", str(out)).returncode == 0
    assert json.loads(out.read_text())["spearman"] == -1.0


def test_an_eval_with_the_filter_too_few_pairs_and_a_wrong_file_are_refused(tmp_path: Path) -> None:
    sel = _select(tmp_path / "s.json", {"a.pt": 1, "b.pt": 2, "c.pt": 3})
    filtered = _alone(tmp_path / "f.json", "a.pt", 9, enabled=True)
    done = run("--select", sel, "--alone", filtered)
    assert done.returncode != 0 and "flown with the filter" in done.stderr
    two = [_alone(tmp_path / f"{m}.json", f"{m}.pt", 5) for m in "ab"]
    done = run("--select", sel, "--alone", *two)
    assert done.returncode == 2 and "need 3 or more" in done.stderr
    done = run("--select", two[0], "--alone", *two)
    assert done.returncode != 0 and "no 'scores'" in done.stderr
