"""``quadnav-sim sweep`` on a local Ray, end to end with a tiny budget: trials train and are evaluated,
the tables and the best model come out (and ship), a trial that raises is recorded as failed while
the others finish, and a sweep killed mid-run resumes and finishes the rest without redoing them."""

from __future__ import annotations

import contextlib
import csv
import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray.tune", reason='the sweep extra is not installed: pip install "quadnav[sweep]"')

pytestmark = pytest.mark.slow

TINY_SET = {
    "episodes": "20", "train_worlds": "1+4", "n_envs": "4", "max_steps": "12", "batch_size": "8",
    "buffer_size": "500", "learning_starts": "16", "checkpoint_every": "5",
}  # fmt: skip
"""TrainConfig overrides of a trial that takes seconds."""
TINY_OPTIONS = ["--eval-every", "10", "--eval-trials", "1", "--final-trials", "1", "--no-progress",
                "--num-cpus", "2"]  # fmt: skip
"""Scores every 10 episodes, one evaluation trial per world, no progress bar, two CPUs."""


def _tiny(*leave_out: str) -> list[str]:
    """The tiny sweep's flags (less the overrides named)."""
    sets = [a for k, v in TINY_SET.items() if k not in leave_out for a in ("--set", f"{k}={v}")]
    return [*sets, *TINY_OPTIONS]


TINY = _tiny()


def _sweep(out: Path, *args: str, timeout_s: float = 240) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "sim_harness.cli", "sweep", "--out", str(out), *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)


def test_a_two_trial_local_sweep_runs_end_to_end_and_its_best_model_ships(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    proc = _sweep(out, "--name", "tiny", "--seeds", "0", "1", *TINY)
    assert proc.returncode == 0, proc.stderr[-3000:]
    records = json.loads((out / "sweep.json").read_text())
    assert [r["status"] for r in records] == ["ok", "ok"]
    assert sorted(r["config"]["seed"] for r in records) == [0, 1]
    for r in records:
        assert r["episodes"] == 20 and r["config"]["name"] == "tiny"
        assert r["eval_all"]["trials"] == 10 and r["eval_held_out"]["trials"] == 3
        run = Path(r["run_dir"])
        assert (run / "checkpoints" / "final.pt").is_file() and (run / "metrics.csv").is_file()
        assert [e["episode"] for e in json.loads((run / "evals.json").read_text())] == [10]
        assert any((run / "tb").iterdir())  # TensorBoard event files
    rows = list(csv.DictReader((out / "sweep.csv").open()))
    assert [row["status"] for row in rows] == ["ok", "ok"] and all(row["model"] for row in rows)
    best = json.loads((out / "best.json").read_text())
    assert best["model"] in {row["model"] for row in rows}
    shipped = tmp_path / "best.pt"
    ship = subprocess.run(
        [sys.executable, "-m", "sim_harness.cli", "ship", "--model", best["model"], "--out", str(shipped)],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert ship.returncode == 0 and shipped.is_file(), ship.stderr


def test_a_trial_that_raises_is_recorded_failed_while_the_other_finishes(tmp_path: Path) -> None:
    out = tmp_path / "sw"
    missing = tmp_path / "no_such_world.yaml"
    proc = _sweep(out, "--name", "tiny", "--grid", f"world_files=[],[{missing}]", *TINY)
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = json.loads((out / "sweep.json").read_text())
    records = {json.dumps(r["config"]["world_files"]): r for r in table}
    assert records["[]"]["status"] == "ok" and records["[]"]["episodes"] == 20
    failed = records[json.dumps([str(missing)])]
    assert failed["status"] == "failed"
    assert "WorldError" in failed["error"] and str(missing) in failed["error"]
    best = json.loads((out / "best.json").read_text())
    assert best["trial_id"] == records["[]"]["trial_id"]


def test_asha_stops_the_trials_whose_scores_fall_behind(tmp_path: Path) -> None:
    """Two trials flying 12-step episodes, then two flying 1-step ones (their evaluations cover a
    fraction of the distance): at the rung of episode 10 ASHA stops the two short ones, the others
    run to the end."""
    out = tmp_path / "sw"
    proc = _sweep(
        out, "--name", "tiny", "--grid", "max_steps=12,1", "--seeds", "0", "1", "--scheduler", "asha",
        "--metric", "distance_m", "--grace-period", "10", "--max-concurrent", "1", *_tiny("max_steps"),
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    table = json.loads((out / "sweep.json").read_text())
    status = {(r["config"]["max_steps"], r["config"]["seed"]): r["status"] for r in table}
    assert status == {(12, 0): "ok", (12, 1): "ok", (1, 0): "stopped", (1, 1): "stopped"}


def _finished_trials(out: Path) -> int:
    """Trials Tune's saved experiment state holds as finished."""
    n = 0
    for f in (out / "tune").glob("experiment_state-*.json"):
        with contextlib.suppress(OSError):
            n = max(n, f.read_text().count("TERMINATED"))
    return n


def test_a_sweep_killed_mid_run_resumes_and_finishes_the_remaining_trials(tmp_path: Path) -> None:
    """Three trials one at a time; the whole process group is killed (SIGKILL) once the saved state
    holds a finished trial; --resume runs the rest and leaves the finished one alone."""
    out = tmp_path / "sw"
    cmd = [sys.executable, "-m", "sim_harness.cli", "sweep", "--out", str(out), "--name", "tiny",
           "--seeds", "0", "1", "2", "--max-concurrent", "1", *TINY]  # fmt: skip
    env = {**os.environ, "TUNE_GLOBAL_CHECKPOINT_S": "0"}  # Tune saves its state at every event
    quiet = subprocess.DEVNULL
    proc = subprocess.Popen(cmd, stdout=quiet, stderr=quiet, start_new_session=True, env=env)
    try:
        while proc.poll() is None and _finished_trials(out) < 1:
            with contextlib.suppress(subprocess.TimeoutExpired):
                proc.wait(timeout=0.2)
        assert proc.poll() is None, "the sweep ended before it could be killed"
    finally:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    assert not (out / "sweep.json").exists()  # killed before the end
    first_runs = {p.name: sorted(q.name for q in p.iterdir()) for p in (out / "runs").iterdir()}

    resumed = _sweep(out, "--resume", "--no-progress")
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    records = json.loads((out / "sweep.json").read_text())
    assert [r["status"] for r in records] == ["ok", "ok", "ok"]
    assert sorted(r["config"]["seed"] for r in records) == [0, 1, 2]
    for trial, runs in first_runs.items():  # every trial kept the run it had begun: none started over
        assert sorted(q.name for q in (out / "runs" / trial).iterdir()) == runs
    assert all(r["episodes"] == 20 for r in records)


def test_without_ray_the_sweep_exits_naming_the_extra(monkeypatch: pytest.MonkeyPatch, capsys) -> None:
    import builtins

    from sim_harness.cli import main

    real_import = builtins.__import__

    def no_ray(name: str, *args, **kwargs):
        if name == "ray" or name.startswith("ray."):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_ray)
    rc = main(["sweep", "--out", "unused", "--seeds", "0"])
    assert rc == 3 and 'pip install "quadnav[sweep]"' in capsys.readouterr().err
