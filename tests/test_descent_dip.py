"""scripts/descent_dip.py: the physics behind the filter's cap at 1 m (docs/results.md)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "descent_dip.py"


def run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, str(SCRIPT), *args], capture_output=True, text=True)


def test_a_1_m_descent_drops_past_its_end_whatever_follows_and_leaves_starts_that_cannot_pass(tmp_path):
    out = tmp_path / "dip.json"
    done = run("--json", str(out))
    assert done.returncode == 0, done.stderr
    r = json.loads(out.read_text())
    drop = r["drop_below_start_m"]
    # whatever follows a 1 m descent, the vehicle goes on down past its end (it ends at 1 m/s)
    assert 1.05 < drop["up"]["least_m"] <= drop["level"]["least_m"] < drop["down"]["least_m"]
    assert drop["down"]["least_m"] > 2.0
    assert r["band_m"] == [0.5, 1.6]
    low, high = r["starts_that_cannot_pass_m"]
    assert low == 1.6 and high == round(0.5 + drop["level"]["least_m"], 3) and high > low
    assert "cannot pass under the ceiling" in done.stdout
    # the filter looks further past the end than the vehicle goes; less far along the stop
    reach = r["filter_reach_past_end_m"]
    assert reach["stop"]["below_descent_end_m"] < reach["velocity"]["below_descent_end_m"]
    assert reach["stop"]["beyond_forward_end_m"] < reach["velocity"]["beyond_forward_end_m"]
    assert reach["stop"]["below_descent_end_m"] >= drop["level"]["least_m"] - 1.0 - 0.05


def test_at_half_scale_every_start_can_pass_and_bad_numbers_are_refused(tmp_path):
    out = tmp_path / "half.json"
    assert run("--primitive-scale", "0.5", "--json", str(out)).returncode == 0
    r = json.loads(out.read_text())
    assert r["starts_that_cannot_pass_m"] is None
    assert r["drop_below_start_m"]["level"]["most_m"] < 0.7
    for bad in (["--primitive-scale", "nan"], ["--clearance-m", "-1"], ["--ceiling-m", "1.0"]):
        done = run(*bad)
        assert done.returncode == 2 and bad[0] in done.stderr, bad
