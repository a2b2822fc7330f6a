"""The HTML report: self-contained, shows every section, and renders to a non-blank page in Chromium."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

import pytest

from quadnav_onboard.record.synthetic import write_synthetic_flight
from quadnav_onboard.review.cli import main

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    d = tmp_path_factory.mktemp("report")
    write_synthetic_flight(d / "a.mcap", depth_hz=4.0, seed=5)
    write_synthetic_flight(d / "b.mcap", crash_at_step=9, depth_hz=4.0, seed=6)
    assert main([str(d / "a.mcap"), str(d / "b.mcap"), "--html", str(d / "r.html"), "-q"]) == 0
    return d / "r.html"


def test_report_is_self_contained_and_has_every_section(report):
    """One file, no external resources; the row table, rates and every section's figure."""
    text = report.read_text()
    assert not re.search(r"(src|href)=[\"']?(https?:|file:|//)", text)
    for heading in (
        "Results across trials",
        "Where it went",
        "Setpoint tracking",
        "What it chose",
        "What it saw",
        "Modes, failsafes and events",
        "Latency",
    ):
        assert heading in text
    assert "success 50%" in text and "collision-free 50%" in text
    assert text.count("data:image/png;base64,") >= 1 + 2 * 7  # overlay + 7 figures per flight
    assert "collision reported" in text and "crash" in text


def test_report_screenshot_in_headless_chromium_is_not_blank(report, tmp_path):
    """Headless Chromium renders the report; the screenshot has plenty of non-white, varied pixels."""
    png = tmp_path / "r.png"
    proc = subprocess.run(
        [
            sys.executable,
            str(ROOT / "scripts" / "screenshot_report.py"),
            str(report),
            str(png),
            "--height",
            "3000",
        ],
        capture_output=True,
        text=True,
        timeout=180,
        check=False,
    )
    assert proc.returncode == 0, proc.stderr + proc.stdout
    stats = json.loads(proc.stdout.strip().splitlines()[-1])
    assert stats["width"] == 1280 and stats["height"] == 3000
    assert stats["nonwhite_fraction"] > 0.05 and stats["pixel_std"] > 20 and not stats["blank"]
