"""End to end: a planner fine-tuned for one lab flies the daemon. The committed lab recipe
(recipes/lab.yaml), shortened, trains a checkpoint; the real-flight config's dry run in the
one-box lab flies exactly that checkpoint over real MAVLink (each sim part its own process), ends
without a crash, and its record and review name the model and the world."""

from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from quadnav_onboard.checkpoint import load_checkpoint
from quadnav_onboard.daemon.config import load_flight_config
from quadnav_onboard.record import read_record

REPO = Path(__file__).resolve().parents[1]
FLIGHT = REPO / "config" / "flight.yaml"


def _train_short_lab_model(out_dir: Path) -> Path:
    """The lab recipe as committed, cut to two small DAgger iterations (the full recipe: 1-2 min)."""
    train = subprocess.run(
        [sys.executable, "-m", "sim_harness.cli", "train", "--recipe", "recipes/lab.yaml", "--seed", "0",
         "--lab-layouts", "4", "--dagger-iterations", "2", "--dagger-episodes", "4", "--n-envs", "4",
         "--out-dir", str(out_dir), "--no-progress"],
        capture_output=True, text=True, timeout=600, check=False, cwd=REPO,
    )
    assert train.returncode == 0, train.stderr[-3000:]
    (model,) = sorted(out_dir.glob("lab__seed0__*/checkpoints/final.pt"))
    return model


@pytest.mark.e2e
@pytest.mark.slow
def test_a_model_trained_by_the_lab_recipe_flies_the_flight_config_dry_run_in_its_lab(tmp_path):
    model = _train_short_lab_model(tmp_path / "runs")
    sha = hashlib.sha256(model.read_bytes()).hexdigest()
    shipped = REPO / "quadnav_onboard" / "models" / "default.pt"
    assert sha != hashlib.sha256(shipped.read_bytes()).hexdigest()  # fine-tuned, not a copy
    cfg = load_flight_config(FLIGHT)
    trained = load_checkpoint(model).meta["train_config"]  # the recipe's lab, with the overrides
    assert trained["lab_world"] == "lab01-free" and trained["lab_layouts"] == 4
    assert trained["lab_flight_config"] == "config/flight.yaml"

    # The flight config's stale-input limits (0.1 s odometry) are the real flight's: on a loaded
    # machine a starved sim process can trip one before the first step. That flight never started
    # the mission, so it is flown again (at most twice more); any other ending is the result.
    for attempt in range(3):
        rec_dir = tmp_path / f"records{attempt}"
        flight = subprocess.run(
            [sys.executable, "-m", "quadnav_onboard.cli", "--dry-run", "--config", str(FLIGHT),
             "--world", "lab03", "--model", str(model), "--record-dir", str(rec_dir), "--json",
             "--log-format", "json"],
            capture_output=True, text=True, timeout=300, check=False, cwd=tmp_path,
        )
        assert flight.returncode in (0, 3), flight.stderr[-3000:]  # goal or a safe stop, never a crash (4)
        summary = json.loads(flight.stdout.splitlines()[-1])
        if not (summary["steps"] == 0 and summary["stop_reason"] in ("stale_odometry", "stale_depth")):
            break
    assert summary["model_sha256"] == sha  # the daemon flew the trained file
    assert summary["crashed"] is False and summary["stop_reason"] != "crash", summary
    assert 1 <= summary["steps"] <= cfg.mission.max_steps, summary

    (record,) = sorted(rec_dir.glob("*.mcap"))
    rec = read_record(record, load_depth=False)
    assert rec.complete and rec.info["world"].endswith("lab03-one-box.yaml")
    assert rec.info["model_sha256"] == sha and rec.info["model_path"] == str(model)

    review = subprocess.run(
        [sys.executable, "-m", "quadnav_onboard.review.cli", str(record), "--json"],
        capture_output=True, text=True, timeout=120, check=False,
    )
    assert review.returncode == 0, review.stderr[-2000:]
    row = json.loads(review.stdout)
    assert row["crashed"] is False and row["world"] == "lab03-one-box"
    assert row["steps"] == summary["steps"]
