"""End to end: a network that reads the primitive scale it flies at. The committed recipe with the
scale lane, shortened, trains a checkpoint from the model it names (widened with the lane); the
real-flight config's dry run flies it over real MAVLink at the flight scale (each sim part its
own process) and ends without a crash, and the eval flies it to the goal at both scales."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from quadnav_onboard.checkpoint import load_checkpoint

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "config" / "flight.yaml"
RECIPE = REPO / "recipes" / (
    "privileged-lab-hinge3-round2-f25-failures-soft-release-e2-noise-paper-margin1-holding-scale.yaml")


@pytest.mark.e2e
@pytest.mark.slow
def test_a_model_that_reads_the_scale_trains_flies_the_dry_run_and_evaluates_at_both_scales(tmp_path):
    out_dir = tmp_path / "runs"
    train = subprocess.run(
        [sys.executable, "-m", "sim_harness.cli", "train", "--recipe", str(RECIPE), "--seed", "0",
         "--name", "scaled", "--lab-layouts", "2", "--dagger-iterations", "1", "--dagger-episodes", "4",
         "--n-envs", "4", "--out-dir", str(out_dir), "--no-progress"],
        capture_output=True, text=True, timeout=600, check=False, cwd=REPO,
    )
    assert train.returncode == 0, train.stderr[-3000:]
    (model,) = sorted(out_dir.glob("scaled__seed0__*/checkpoints/final.pt"))
    assert load_checkpoint(model).network.scale_input
    sha = hashlib.sha256(model.read_bytes()).hexdigest()

    # As in the lab model's dry run: a flight that a starved sim process stopped before its first
    # step (stale input) is flown again, at most twice more; any other ending is the result.
    for attempt in range(3):
        flight = subprocess.run(
            [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--config", str(FLIGHT),
             "--world", "lab01", "--model", str(model), "--record-dir", str(tmp_path / f"rec{attempt}"),
             "--json", "--log-format", "json"],
            capture_output=True, text=True, timeout=300, check=False, cwd=tmp_path,
        )
        assert flight.returncode in (0, 3), flight.stderr[-3000:]  # goal or a safe stop, never a crash (4)
        summary = json.loads(flight.stdout.splitlines()[-1])
        if not (summary["steps"] == 0 and summary["stop_reason"] in ("stale_odometry", "stale_depth")):
            break
    assert summary["model_sha256"] == sha
    assert summary["crashed"] is False and summary["steps"] >= 1, summary

    for scale in ("0.5", "1.0"):
        ev = subprocess.run(
            [sys.executable, "-m", "sim_harness.cli", "eval", "--model", str(model), "--world", "env01",
             "--trials", "2", "--seed", "0", "--primitive-scale", scale, "--no-progress",
             "--json", str(tmp_path / f"eval{scale}.json")],
            capture_output=True, text=True, timeout=300, check=False, cwd=REPO,
        )
        assert ev.returncode == 0, ev.stderr[-3000:]
        rows = json.loads((tmp_path / f"eval{scale}.json").read_text())["rows"]
        assert [r["outcome"] for r in rows] == ["goal", "goal"]  # Env 1 is free: told either scale, it flies
