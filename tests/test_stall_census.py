"""scripts/stall_census.py: the classes of a decision, and a census that flies the eval's flights."""

from __future__ import annotations

import importlib.util as ilu
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "stall_census.py"


def _module():
    spec = ilu.spec_from_file_location("stall_census", SCRIPT)
    mod = ilu.module_from_spec(spec)
    assert spec.loader is not None
    spec.loader.exec_module(mod)
    return mod


def test_each_decision_falls_in_the_class_of_what_was_allowed_and_chosen() -> None:
    mod = _module()
    forward = np.array([True, True, False, False])
    q = np.array([
        [5.0, 1.0, 2.0, 0.0],  # first choice forward, allowed: forward
        [1.0, 0.0, 5.0, 2.0],  # first choice a hold, allowed, a forward one allowed too: held back
        [9.0, 0.0, 5.0, 2.0],  # first choice forward but vetoed, next best a hold: overruled back
        [9.0, 8.0, 5.0, 2.0],  # no forward primitive allowed: boxed in
    ])
    allowed = np.array([
        [True, True, True, True],
        [True, True, True, True],
        [False, True, True, True],
        [False, False, True, True],
    ])
    flown, cls = mod.classify(q, allowed, forward)
    assert flown.tolist() == [0, 2, 2, 2]
    assert [mod.CLASSES[k] for k in cls] == ["forward", "held_back", "overruled_back", "boxed_in"]


def test_the_census_flies_the_flights_eval_flies_and_counts_each_of_their_decisions(tmp_path) -> None:
    """Same outcomes as ``evaluate`` with the same model, worlds and seed; one class per decision."""
    from quadnav_onboard.policy import Policy
    from sim_harness.rl.evaluate import FilterOverrules, env_config_for_policy, evaluate, policy_greedy_fn
    from sim_harness.world import load_world, resolve_world_arg

    out = tmp_path / "c.json"
    run = subprocess.run([sys.executable, str(SCRIPT), "--world", "env03", "--trials", "3", "--seed", "5",
                          "--json", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())

    policy = Policy.from_path(r["model"])
    cfg = env_config_for_policy(policy, max_steps=120, start_jitter_m=0.5)
    assert cfg.shield.enabled  # the census flies with the filter; so must the reference
    decisions = FilterOverrules()  # counts every decision a running flight takes, independently
    rows = evaluate(policy_greedy_fn(policy), [load_world(resolve_world_arg("env03"))], 3, 5, cfg,
                    overrules=decisions)
    outcomes: dict[str, int] = {}
    for row in rows:
        outcomes[row.outcome] = outcomes.get(row.outcome, 0) + 1
    assert r["flights"] == 3 and r["outcomes"] == outcomes
    assert sum(sum(c.values()) for c in r["decisions"].values()) == decisions.decisions > 0

    refused = subprocess.run([sys.executable, str(SCRIPT), "--shield", "off"], capture_output=True, text=True)
    assert refused.returncode == 2 and "with the filter" in refused.stderr
    missing = tmp_path / "nowhere.yaml"
    bad = subprocess.run([sys.executable, str(SCRIPT), "--world", str(missing)],
                         capture_output=True, text=True)
    assert bad.returncode == 2 and "nowhere.yaml" in bad.stderr and "Traceback" not in bad.stderr


def test_under_a_flight_config_the_census_flies_what_eval_flies_there(tmp_path) -> None:
    """``--flight-config``: the lab flights of ``quadnav-sim eval --flight-config`` (its limits,
    the room known to the filter, the depth noise), outcome for outcome and decision for decision;
    the flags it sets itself are refused beside it."""
    from sim_harness.cli import main

    repo = SCRIPT.parents[1]
    flags = ["--world", "lab02", "--flight-config", "config/flight.yaml", "--trials", "3", "--seed", "2"]
    ev = tmp_path / "eval.json"
    assert main(["eval", *flags, "--json", str(ev), "--no-progress"]) == 0
    e = json.loads(ev.read_text())
    out = tmp_path / "c.json"
    run = subprocess.run([sys.executable, str(SCRIPT), *flags, "--json", str(out)],
                         capture_output=True, text=True, cwd=repo)
    assert run.returncode == 0, run.stderr
    r = json.loads(out.read_text())
    outcomes: dict[str, int] = {}
    for row in e["rows"]:
        outcomes[row["outcome"]] = outcomes.get(row["outcome"], 0) + 1
    assert r["outcomes"] == outcomes
    assert sum(sum(c.values()) for c in r["decisions"].values()) == e["filter_overrules"]["decisions"]
    for outcome, n in r["boxed_in_by_the_view"].items():  # a share of the boxed-in decisions
        assert 0 <= n <= r["decisions"][outcome]["boxed_in"]

    both = subprocess.run([sys.executable, str(SCRIPT), *flags, "--max-steps", "10"],
                          capture_output=True, text=True, cwd=repo)
    assert both.returncode == 2 and "--flight-config sets" in both.stderr


def test_the_teacher_labels_the_held_back_states_and_goes_on_where_the_way_is_open() -> None:
    """A student that always hovers holds back at every decision in an open world; the privileged
    teacher, asked in the same states, flies forward in every one."""
    from quadnav_onboard.policy import DEFAULT_MODEL_PATH, Policy
    from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
    from sim_harness.rl.config import TrainConfig
    from sim_harness.rl.evaluate import env_config_for_policy
    from sim_harness.rl.train import privileged_teacher
    from sim_harness.world import parse_world

    hover = DEFAULT_DIRECTIONS.index((0, 0, 0))

    class Hoverer:
        def q_values_batch(self, depth, rel, scale_m=None):
            q = np.zeros((depth.shape[0], len(DEFAULT_DIRECTIONS)), dtype=np.float32)
            q[:, hover] = 1.0
            return q

    world = parse_world({
        "name": "open",
        "path": {"waypoints": [[0.0, 0.0, 2.0], [8.0, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": [],
    })
    cfg = env_config_for_policy(Policy.from_path(DEFAULT_MODEL_PATH), max_steps=6)
    teacher = privileged_teacher(TrainConfig(teacher_respect_filter=True), cfg.primitives.scale_m)
    assert teacher.config.respect_filter
    out = _module().census(Hoverer(), [world], 2, 0, cfg, teacher=teacher)
    held = {o: c["held_back"] for o, c in out["decisions"].items()}
    assert sum(held.values()) > 0 and sum(c["forward"] for c in out["decisions"].values()) == 0
    assert out["held_back_teacher_forward"] == held
    assert "held_back_teacher_forward" not in _module().census(Hoverer(), [world], 1, 0, cfg)


def test_a_teacher_the_census_cannot_rebuild_is_refused() -> None:
    """The filter teacher's recipes, and flights under a flight config (the lab task's teacher is
    its own), exit 2 with the reason."""
    repo = SCRIPT.parents[1]
    for extra in (["--teacher-recipe", str(repo / "recipes" / "filter-teacher.yaml"), "--world", "env01"],
                  ["--teacher-recipe", str(repo / "recipes" / "shipped.yaml"),
                   "--flight-config", str(repo / "config" / "flight.yaml"), "--world", "lab01"]):
        run = subprocess.run([sys.executable, str(SCRIPT), *extra, "--trials", "1"],
                             capture_output=True, text=True)
        assert run.returncode == 2 and "only the privileged teacher" in run.stderr, run.stderr


def test_the_privileged_teacher_keeps_to_the_filter_only_where_its_task_learns_from_it() -> None:
    from sim_harness.rl.config import TrainConfig
    from sim_harness.rl.train import privileged_teacher

    everywhere = TrainConfig(teacher_respect_filter=True)
    at_half = TrainConfig(teacher_respect_filter=True, imitation_filter_scales=(0.5,))
    assert privileged_teacher(everywhere, 1.0).config.respect_filter
    assert privileged_teacher(at_half, 0.5).config.respect_filter
    assert not privileged_teacher(at_half, 1.0).config.respect_filter
    assert not privileged_teacher(TrainConfig(), 0.5).config.respect_filter
