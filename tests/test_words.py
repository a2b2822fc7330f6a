"""The repository speaks of the product: no tracked file names a work round by number, a tracker
issue by number, or the process that wrote it. The product's own "stop" (StopReason, the stop
ladder, "stop the flight") stays legal: only "stop" followed by a number is refused."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent

WORDS = re.compile(
    "|".join(
        [
            r"\bstop \d+",  # a work round by number
            r"\bround \d+",  # the same, renamed
            r"\bthis " r"stop\b",
            r"\bhelp" r"er ses" r"sion",
            r"\bissue #?\d+",  # a tracker issue by number
            r"\bthe brief\b",
        ]
    ),
    re.IGNORECASE,
)

EXCLUDED = {"tests/test_words.py"}
"""This file, which must spell the words to refuse them."""


def tracked_files() -> list[str]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True, timeout=60
        ).stdout
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.skip(f"not a git checkout: {exc}")
    return [p for p in out.decode("utf-8").split("\0") if p]


def hits(text: str) -> list[str]:
    return [m.group(0) for m in WORDS.finditer(text)]


def test_the_pattern_refuses_round_and_issue_numbers_but_not_the_product_s_stop() -> None:
    """The words are found however they are cased; the product's stop vocabulary is not."""
    stop_n, this_stop, issue_n = "Stop" + " 14", "this" + " stop", "issue" + " 26"
    assert hits(f"as measured in {stop_n}'s weights") == [stop_n]
    assert hits(f"see {issue_n} and {this_stop}") == [issue_n, this_stop]
    assert hits("the brief allows 0.02") == ["the brief"]
    assert hits("measured in round 15") == ["round 15"]
    for legal in (
        "StopReason.GEOFENCE ends the flight",
        "the stop ladder: hold, land, disarm",
        "stop the flight at once",
        "a stop request at step 3",
        "stops 2 m short",
    ):
        assert hits(legal) == [], legal


def test_no_tracked_file_holds_work_round_words() -> None:
    """git ls-files, every text file but this one: no work-round number, round reference, assistant-run name,
    "issue N" or "the brief" (a file named here needs its wording changed, not an exclusion)."""
    files = tracked_files()
    assert "README.md" in files
    found: list[str] = []
    for rel in files:
        if rel in EXCLUDED:
            continue
        path = REPO / rel
        if not path.is_file():  # deleted in the working tree, not yet committed
            continue
        data = path.read_bytes()
        if b"\0" in data[:8192]:  # binary (weights, images)
            continue
        for lineno, line in enumerate(data.decode("utf-8", errors="replace").splitlines(), 1):
            found += [f"{rel}:{lineno}: {word!r}" for word in hits(line)]
    assert not found, "work-round words in tracked files:\n" + "\n".join(found)
