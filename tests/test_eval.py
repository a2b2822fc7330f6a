"""Evaluation: success counting on scripted policies, the table, and the eval command."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from quadnav_onboard.checkpoint import save_checkpoint
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.shield import ShieldConfig
from sim_harness.cli import main
from sim_harness.cmd_eval import shown_path
from sim_harness.env import EnvConfig
from sim_harness.rl.evaluate import EvalRow, evaluate, format_table, summarize
from sim_harness.world import parse_world

FORWARD, LEFT = 4, 16


def _world(name: str, obstacles: list) -> object:
    return parse_world(
        {"name": name, "path": {"waypoints": [[0, 0, 2], [12, 0, 2]]}, "obstacles": obstacles}, "test"
    )


def _forward(depth: np.ndarray, rel: np.ndarray, allowed: np.ndarray) -> np.ndarray:
    return np.full(len(depth), FORWARD)


def test_success_counting_on_a_scripted_policy() -> None:
    free = _world("free", [])
    wall = _world("wall", [{"type": "box", "center": [5, 0, 2], "size": [0.2, 20, 20]}])
    rows = evaluate(_forward, [free, wall], trials=3, seed=0, env_config=EnvConfig(max_steps=30))
    assert [r.world for r in rows] == ["free"] * 3 + ["wall"] * 3
    assert [r.outcome for r in rows] == ["goal"] * 3 + ["crash"] * 3
    assert [r.crash for r in rows] == [False] * 3 + [True] * 3
    assert all(r.distance_m >= 11.0 for r in rows[:3]) and all(r.distance_m < 5.0 for r in rows[3:])
    s = summarize(rows)
    assert s["trials"] == 6 and s["goal"] == 3 and s["collision_free"] == 3
    assert s["success_rate"] == 0.5 and s["collision_free_rate"] == 0.5 and s["success_among_safe"] == 1.0


def test_a_worlds_flights_depend_on_its_place_in_the_list_not_on_the_other_worlds() -> None:
    free, other = _world("free", []), _world("other", [{"type": "sphere", "center": [6, 3, 2], "radius": 1}])
    cfg = EnvConfig(max_steps=10)

    def flights(worlds: list) -> list[tuple[float, float]]:
        rows = evaluate(_forward, worlds, trials=4, seed=3, env_config=cfg)
        return [(r.distance_m, r.total_reward) for r in rows if r.world == "free"]

    second = flights([other, free])
    assert flights([free, free])[4:] == second  # the same place: seed 1009 * 3 + 1
    assert flights([free]) != second  # alone it is first: seed 1009 * 3, other starts


def test_summary_separates_safe_failures_from_crashes() -> None:
    def row(outcome: str) -> EvalRow:
        return EvalRow("w", 0, 1.0, 1.0, outcome == "crash", 0.0, outcome)

    s = summarize([row("goal"), row("timeout"), row("deviation"), row("crash")])
    assert s["success_rate"] == 0.25
    assert s["collision_free_rate"] == 0.75
    assert abs(s["success_among_safe"] - 1 / 3) < 1e-12


def test_sideways_policy_deviates_and_hovering_times_out() -> None:
    free = _world("free", [])
    rows = evaluate(lambda d, r, a: np.full(len(d), LEFT), [free], 2, 0, EnvConfig(max_steps=30))
    assert {r.outcome for r in rows} == {"deviation"}
    rows = evaluate(lambda d, r, a: np.full(len(d), 13), [free], 2, 0, EnvConfig(max_steps=7))
    assert {r.outcome for r in rows} == {"timeout"} and all(r.time_s == 7.0 for r in rows)


def test_table_has_the_papers_columns() -> None:
    text = format_table([EvalRow("env01-free", 0, 60.0, 57.0, False, 12.15, "goal")])
    assert "distance (m)" in text and "time (s)" in text and "crash" in text and "reward" in text
    assert "60.00" in text and "goal" in text


def test_eval_command_writes_json_rows_for_any_world_file(tmp_path, capsys) -> None:
    world = tmp_path / "mine.yaml"
    world.write_text("name: mine\npath:\n  waypoints: [[0, 0, 2], [8, 0, 2]]\n")
    model = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig()))
    out = tmp_path / "eval.json"
    rc = main(
        [
            "eval",
            "--model",
            str(model),
            "--world",
            str(world),
            "--trials",
            "2",
            "--json",
            str(out),
            "--no-progress",
            "--max-steps",
            "15",
        ]
    )
    assert rc == 0
    data = json.loads(out.read_text())
    assert len(data["rows"]) == 2 and data["rows"][0]["world"] == "mine"
    assert data["summary"]["trials"] == 2
    assert "success" in capsys.readouterr().out
    assert (data["model"], data["worlds"]) == (str(model), [str(world)])  # outside the working dir


def test_eval_files_name_paths_under_the_working_directory_relative_to_it(tmp_path, monkeypatch) -> None:
    """Run from the repository root, an eval file names its model and worlds the same on every
    machine; a path elsewhere stays whole, and a generated world's label is kept as it is."""
    (tmp_path / "models").mkdir()
    monkeypatch.chdir(tmp_path)
    assert shown_path(tmp_path / "models" / "m.pt") == "models/m.pt"
    assert shown_path(Path("models/m.pt")) == "models/m.pt"
    elsewhere = tmp_path.parent / "other.pt"
    assert shown_path(elsewhere) == str(elsewhere)
    assert shown_path("<procgen procgen001 seed 4242>") == "<procgen procgen001 seed 4242>"


def test_eval_command_reports_a_bad_world_without_a_traceback(tmp_path, capsys) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\n")
    model = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig()))
    rc = main(["eval", "--model", str(model), "--world", str(bad), "--no-progress"])
    assert rc == 2
    err = capsys.readouterr().err
    assert "bad.yaml" in err and "Traceback" not in err


def test_eval_command_reports_a_missing_model(tmp_path, capsys) -> None:
    rc = main(["eval", "--model", str(tmp_path / "none.pt"), "--no-progress"])
    assert rc == 2 and "not found" in capsys.readouterr().err


def test_at_primitive_scale_slows_the_setpoint_and_lengthens_the_step_limit() -> None:
    """Half-size primitives: the moving setpoint still advances one primitive per step (speed
    halved) and the step limit doubles unless given; obstacles and waypoints are untouched."""
    from sim_harness.env import at_primitive_scale

    w = _world("w", [{"type": "box", "center": [6, 0, 2], "size": [1, 1, 1]}])
    cfg, (slow,) = at_primitive_scale(EnvConfig(max_steps=120), [w], 0.5)
    assert cfg.primitives.scale_m == 0.5 and cfg.max_steps == 240
    assert slow.path.speed_m_s == w.path.speed_m_s / 2
    assert np.array_equal(slow.path.waypoints_m, w.path.waypoints_m) and slow.obstacles == w.obstacles
    assert at_primitive_scale(EnvConfig(max_steps=120), [w], 0.5, max_steps=30)[0].max_steps == 30
    shielded = EnvConfig(shield=ShieldConfig(enabled=True, memory_steps=4))
    assert at_primitive_scale(shielded, [w], 0.5)[0].shield.memory_steps == 8  # the same 4 m of travel


def test_eval_at_the_flight_scale_goes_slower_and_says_so(tmp_path) -> None:
    """``--primitive-scale 0.5``: straight ahead on an 8 m free path takes twice the steps, and the
    JSON records the scale and step limit flown."""
    from quadnav_onboard.daemon.testing import constant_action_checkpoint

    world = tmp_path / "free.yaml"
    world.write_text("name: free\npath:\n  waypoints: [[0, 0, 2], [8, 0, 2]]\n")
    model = tmp_path / "straight.pt"
    constant_action_checkpoint(str(model), FORWARD)
    steps: dict[str, float] = {}
    for scale in ("1.0", "0.5"):
        out = tmp_path / f"eval{scale}.json"
        argv = ["eval", "--model", str(model), "--world", str(world), "--trials", "1", "--seed", "0"]
        assert main([*argv, "--primitive-scale", scale, "--json", str(out), "--no-progress"]) == 0
        data = json.loads(out.read_text())
        assert data["primitive_scale_m"] == float(scale) and data["max_steps"] == int(120 / float(scale))
        (row,) = data["rows"]
        assert row["outcome"] == "goal"
        steps[scale] = row["time_s"]  # steps x 1 s primitives
    assert 1.8 * steps["1.0"] <= steps["0.5"] <= 2.2 * steps["1.0"]


def test_eval_without_start_jitter_flies_every_trial_alike_and_says_so(tmp_path, capsys) -> None:
    """``--start-jitter-m 0`` (how the dry run starts): the trials of a world are the same flight,
    from the path's start; with the default jitter they are not, and each row says where within
    the jitter it began. A negative jitter is refused before any flight."""
    from quadnav_onboard.daemon.testing import constant_action_checkpoint

    world = tmp_path / "free.yaml"
    world.write_text("name: free\npath:\n  waypoints: [[0, 0, 2], [8, 0, 2]]\n")
    model = tmp_path / "straight.pt"
    constant_action_checkpoint(str(model), FORWARD)
    argv = ["eval", "--model", str(model), "--world", str(world), "--trials", "3", "--no-progress"]
    rewards, starts = {}, {}
    for jitter in ("0", "0.5"):
        out = tmp_path / f"eval{jitter}.json"
        assert main([*argv, "--start-jitter-m", jitter, "--json", str(out)]) == 0
        data = json.loads(out.read_text())
        assert data["start_jitter_m"] == float(jitter)
        rewards[jitter] = {r["total_reward"] for r in data["rows"]}
        starts[jitter] = [tuple(r["start_m"]) for r in data["rows"]]
    assert len(rewards["0"]) == 1 and len(rewards["0.5"]) == 3
    assert starts["0"] == [(0.0, 0.0, 2.0)] * 3  # the path's start, where every row says it began
    assert len(set(starts["0.5"])) == 3
    assert all(max(abs(a - b) for a, b in zip(s, (0, 0, 2), strict=True)) <= 0.5 for s in starts["0.5"])
    with pytest.raises(SystemExit) as exc:
        main([*argv, "--start-jitter-m", "-0.1"])
    assert exc.value.code == 2
    assert "--start-jitter-m: must be >= 0 and finite, got -0.1" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["eval", "select"])
def test_a_scale_that_is_not_positive_is_refused_before_any_flight(command: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main([command, "--primitive-scale", "0", "--no-progress"])
    assert exc.value.code == 2
    assert "--primitive-scale: must be > 0 and finite, got 0" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flags", "index", "trial"),
    [
        (["--world", "env05", "--world", "env04", "--max-steps", "25"], 0, 1),
        (["--world", "lab01", "--world", "lab02", "--flight-config", "config/flight.yaml"], 1, 2),
        (["--world", "lab01", "--layouts", "2", "--flight-config", "config/flight.yaml"], 1, 2),
    ],
    ids=["paper-world", "lab-under-the-flight-config", "a-random-layout-of-the-lab"],
)
def test_trace_flight_script_replays_the_flight_eval_flew(flags, index, trial, tmp_path, capsys) -> None:
    """scripts/trace_flight.py flies trial T of world I as ``quadnav-sim eval`` with the same flags
    does (same seed, filter and the room known to it, scale; under a flight config its limits and
    the depth noise): it ends as eval's row for that trial, one line per decision."""
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[1]
    common = [*flags, "--trials", "3", "--seed", "3"]
    out = tmp_path / "eval.json"
    assert main(["eval", *common, "--json", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    row = json.loads(out.read_text())["rows"][index * 3 + trial]
    script = repo / "scripts" / "trace_flight.py"
    lines = subprocess.run(
        [sys.executable, str(script), *common, "--world-index", str(index), "--trial", str(trial)],
        check=True, capture_output=True, text=True, cwd=repo,
    ).stdout.splitlines()
    assert lines[0] == row["world"]
    assert lines[-1] == f"outcome: {row['outcome']}"
    # a primitive lasts 1 s in both (1 m at 1 m/s; the flight config's 0.5 m at 0.5 m/s)
    steps = [line for line in lines if line[:3].strip().isdigit()]
    assert len(steps) == round(row["time_s"])
    import ast

    for line in steps:  # the first three: (action, allowed, the filter's clearance, the true one)
        top = ast.literal_eval(line[line.rindex("[("):])
        assert len(top) == 3 and all(len(x) == 4 and np.isfinite(x[2]) and np.isfinite(x[3]) for x in top)


def test_trace_flight_script_lists_every_primitive_with_top_18() -> None:
    """--top 18 lists all 18 primitives at each decision, each once, the flown one among them;
    --top 0 is refused."""
    import ast
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "trace_flight.py"
    common = [sys.executable, str(script), "--world", "env04", "--max-steps", "6", "--trials", "2"]
    lines = subprocess.run([*common, "--top", "18"], check=True, capture_output=True, text=True).stdout
    steps = [line for line in lines.splitlines() if line[:3].strip().isdigit()]
    assert steps
    for line in steps:
        assert "top 18 (" in line
        listed = ast.literal_eval(line[line.rindex("[("):])
        assert sorted(a for a, *_ in listed) == list(range(18))
        flown = int(line.split(" flies ")[1].split()[0])
        assert any(a == flown and allowed for a, allowed, *_ in listed)  # the filter allowed what flew
    bad = subprocess.run([*common, "--top", "0"], capture_output=True, text=True, check=False)
    assert bad.returncode == 2 and "--top: bad value 0" in bad.stderr


def test_trace_flight_script_refuses_a_world_index_past_the_list() -> None:
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "scripts" / "trace_flight.py"
    got = subprocess.run([sys.executable, str(script), "--world", "env01", "--world-index", "1"],
                         capture_output=True, text=True, check=False)
    assert got.returncode == 2 and "the list has 1 worlds" in got.stderr and "Traceback" not in got.stderr
    bare = subprocess.run([sys.executable, str(script), "--world", "lab01", "--layouts", "2"],
                          capture_output=True, text=True, check=False)
    assert bare.returncode == 2 and "--layouts N needs --flight-config" in bare.stderr


def test_camera_fov_script_changes_what_the_sim_renders_and_runs_the_command(tmp_path) -> None:
    """scripts/with_camera_fov.py (the 90-deg experiment of docs/results.md): in its process the
    env renders through the given field of view, and the quadnav-sim command after ``--`` runs."""
    import subprocess
    import sys
    from pathlib import Path

    from sim_harness.world import paper_world_path

    script = Path(__file__).resolve().parents[1] / "scripts" / "with_camera_fov.py"
    probe = (
        "import sys, numpy as np\n"
        "import sim_harness.env as E\n"
        "from quadnav_onboard.preprocess import PreprocessConfig\n"
        "from sim_harness.world import load_world, paper_world_path\n"
        "w = load_world(paper_world_path(6))\n"
        "pos, yaw = np.array([[8.5, 0, 3.4]]), np.array([0.0])\n"
        "look = lambda: E.render_inputs(w, pos, yaw, PreprocessConfig()).mean\n"
        "before = look()\n"
        f"sys.path.insert(0, {str(script.parent)!r})\n"
        "import with_camera_fov as m\n"
        "m.patch_camera(90, 90)\n"
        "print(float(np.abs(look() - before).max()))\n"
    )
    changed = subprocess.run([sys.executable, "-c", probe], check=True, capture_output=True, text=True)
    assert float(changed.stdout.strip()) > 0.1

    out = tmp_path / "e.json"
    run = subprocess.run(
        [sys.executable, str(script), "--hfov", "90", "--vfov", "90", "--", "eval", "--world",
         str(paper_world_path(1)), "--trials", "1", "--max-steps", "3", "--json", str(out), "--no-progress"],
        capture_output=True, text=True,
    )
    assert run.returncode == 0, run.stderr
    assert "90.0 x 90.0 deg" in run.stderr
    assert len(json.loads(out.read_text())["rows"]) == 1

    bad = subprocess.run([sys.executable, str(script), "--hfov", "0", "--vfov", "90", "--", "eval"],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "--hfov 0" in bad.stderr


@pytest.mark.parametrize("count", ["0", "-3", "two"])
def test_procedural_needs_at_least_one_world(count: str, capsys) -> None:
    """``--procedural 0`` is a usage error, not the full paper evaluation."""
    with pytest.raises(SystemExit) as exc:
        main(["eval", "--procedural", count, "--no-progress"])
    assert exc.value.code == 2
    assert "--procedural: must be" in capsys.readouterr().err


def test_procedural_and_world_files_are_not_mixed(tmp_path, capsys) -> None:
    """--procedural does not replace the --world files without a word: giving both is refused."""
    model = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig()))
    rc = main(["eval", "--model", str(model), "--world", "env01", "--procedural", "2", "--no-progress"])
    assert rc == 2 and "give --world or --procedural N, not both" in capsys.readouterr().err


@pytest.mark.parametrize(("flag", "value"), [("--primitive-scale", "inf"), ("--start-jitter-m", "nan")])
def test_non_finite_flight_flags_are_refused(flag: str, value: str, capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["eval", flag, value, "--no-progress"])
    assert exc.value.code == 2 and f"{flag}: must be" in capsys.readouterr().err


@pytest.mark.parametrize(
    ("flag", "value"), [("--seed", "-1"), ("--procedural-seed", "-5"), ("--trials", "0")]
)
def test_seeds_and_counts_out_of_range_are_usage_errors(flag: str, value: str, capsys) -> None:
    """A negative seed is a usage error before anything loads, not a numpy traceback mid-run."""
    with pytest.raises(SystemExit) as exc:
        main(["eval", flag, value, "--no-progress"])
    assert exc.value.code == 2 and f"{flag}: must be" in capsys.readouterr().err


def test_the_filters_overrules_of_the_first_choice_are_counted() -> None:
    """A policy that always wants straight ahead into a wall: the filter vetoes it near the wall,
    and the count says how often it overruled that first choice among the decisions taken."""
    from sim_harness.rl.evaluate import FilterOverrules

    def first_choice_ahead(depth, rel, allowed):
        return np.where(allowed[:, FORWARD], FORWARD, np.argmax(allowed, axis=1))

    wall = _world("wall", [{"type": "box", "center": [5, 0, 2], "size": [0.2, 20, 20]}])
    free = _world("free", [])
    shielded = EnvConfig(max_steps=20, shield=ShieldConfig(enabled=True))
    counts = {}
    for world in (free, wall):
        counts[world.name] = FilterOverrules()
        evaluate(first_choice_ahead, [world], trials=2, seed=0, env_config=shielded,
                 overrules=counts[world.name])
    assert counts["free"].decisions > 0 and counts["free"].overruled == 0
    assert 0 < counts["wall"].overruled <= counts["wall"].decisions
    assert counts["wall"].to_dict()["rate"] == counts["wall"].overruled / counts["wall"].decisions
