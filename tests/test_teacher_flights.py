"""scripts/teacher_flights.py: the privileged teacher flown in an eval's flights, and the eval's hook
that hands a planner each world's env."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "teacher_flights.py"


def test_each_world_start_hands_over_the_reset_env_before_the_first_decision() -> None:
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from sim_harness.rl.evaluate import env_config_for_policy, eval_starts, evaluate
    from sim_harness.world import load_world, resolve_world_arg

    cfg = env_config_for_policy(Policy.from_path(DEFAULT_MODEL_PATH), max_steps=3)
    worlds = [load_world(resolve_world_arg(w)) for w in ("env01", "env03")]
    seen: list[tuple[str, np.ndarray, int]] = []
    calls: list[int] = []

    def act(depth, rel, allowed):
        calls.append(len(seen))
        return np.zeros(len(depth), dtype=np.int64)

    evaluate(act, worlds, 2, 7, cfg,
             on_world_start=lambda w, env: seen.append((w.name, env.pos_m.copy(), int(env.steps.max()))))
    assert [s[0] for s in seen] == [w.name for w in worlds]
    for i, (world, (_, pos, steps)) in enumerate(zip(worlds, seen, strict=True)):
        assert steps == 0
        assert np.allclose(pos, eval_starts(world, i, 2, 7, cfg))
    assert calls[0] == 1  # the first world's env was handed over before its first decision


def test_the_teacher_flies_a_free_world_to_its_goal_from_the_eval_starts(tmp_path) -> None:
    out = tmp_path / "t.json"
    run = subprocess.run([sys.executable, str(SCRIPT), "--world", "env01", "--trials", "2", "--seed", "3",
                          "--primitive-scale", "0.5", "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    assert [row["outcome"] for row in r["rows"]] == ["goal", "goal"]
    assert r["summary"]["success_rate"] == 1.0
    assert "goal 100.0%" in run.stdout


def test_a_margin_out_of_range_is_refused_by_name() -> None:
    run = subprocess.run([sys.executable, str(SCRIPT), "--world", "env01", "--margin-m", "nan"],
                         capture_output=True, text=True)
    assert run.returncode == 2
    assert "--margin-m" in run.stderr and "nan" in run.stderr


def test_with_the_filter_on_the_script_counts_its_vetoes_of_the_teacher(tmp_path) -> None:
    out = tmp_path / "t.json"
    flags = ["--world", "env03", "--trials", "2", "--seed", "3", "--primitive-scale", "0.5",
             "--shield", "on", "--respect-filter", "--json", str(out)]
    run = subprocess.run([sys.executable, str(SCRIPT), *flags], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    v = r["filter_vetoes"]
    assert r["respect_filter"] is True
    # one decision per step of each flight (a 0.5 m primitive lasts 1 s at 0.5 m/s)
    assert v["decisions"] == round(sum(row["time_s"] for row in r["rows"]))
    assert v["vetoed"] == 0  # respecting the filter, it never chooses what the filter vetoes
    assert "would veto the teacher's choice" in run.stdout


def test_respecting_the_filter_needs_it_on() -> None:
    run = subprocess.run([sys.executable, str(SCRIPT), "--world", "env01", "--respect-filter"],
                         capture_output=True, text=True)
    assert run.returncode == 2
    assert "--respect-filter" in run.stderr and "--shield on" in run.stderr


def test_the_teacher_pilot_refuses_to_act_before_it_is_handed_a_world_env() -> None:
    from sim_harness.rl.teacher import Teacher, TeacherPilot

    pilot = TeacherPilot(Teacher())
    with pytest.raises(RuntimeError, match="on_world_start"):
        pilot.act(np.zeros((1, 1, 32, 32)), np.zeros((1, 3)), np.ones((1, 18), dtype=bool))
