"""``quadnav-sim select``: the checkpoint-selection rule, flown for real on tiny budgets."""

from __future__ import annotations

import json

from quadnav_onboard.daemon.testing import constant_action_checkpoint
from sim_harness.cli import main


def test_select_scores_goals_minus_crashes_on_train_and_dev_sets_only(tmp_path, capsys):
    """Each checkpoint flies Env 1-7 at two seeds and 8 development worlds at two seeds; the score is
    goals minus crashes; checkpoints tied at the top fly the same flights alone, and the tie goes to
    the best score alone, then to the one listed first; a bad one is a clear error."""
    straight, hover, twin = tmp_path / "straight.pt", tmp_path / "hover.pt", tmp_path / "twin.pt"
    constant_action_checkpoint(str(straight), 4)
    constant_action_checkpoint(str(hover), 13)
    twin.write_bytes(hover.read_bytes())
    out = tmp_path / "sel.json"
    argv = ["select", str(straight), str(hover), str(twin), "--trials", "1", "--max-steps", "30"]
    argv.append("--no-progress")
    assert main([*argv, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    flights = {k: v["flights"] for k, v in data["scores"][0].items() if isinstance(v, dict) and k != "alone"}
    assert flights == {"train_seed0": 7, "train_seed1000": 7, "dev_seed0": 8, "dev_seed1": 8}
    for s in data["scores"]:
        parts = [v for k, v in s.items() if isinstance(v, dict) and k != "alone"]
        assert s["goals"] == sum(p["goals"] for p in parts) and s["score"] == s["goals"] - s["crashes"]
    _, first, second = data["scores"]
    assert second == {**first, "model": str(twin)}  # the same weights score the same
    # in 30 steps nothing arrives and the filter stops every crash: all three tie at 0 ...
    assert [s["score"] for s in data["scores"]] == [0, 0, 0]
    assert data["tie_break"]["tied"] == [str(straight), str(hover), str(twin)]
    # ... and alone flying straight crashes where hovering does not
    assert data["scores"][0]["alone"]["crashes"] > 0 == data["scores"][1]["alone"]["crashes"]
    assert all(s["alone"]["score"] == s["alone"]["goals"] - s["alone"]["crashes"] for s in data["scores"])
    assert data["chosen"] == str(hover)  # best alone; its twin, as good, is listed after it
    assert "<- chosen" in capsys.readouterr().out
    assert "teacher" not in data and "missed_by_teacher_too" not in data["scores"][0]
    assert main(["select", str(tmp_path / "missing.pt"), "--no-progress"]) == 2
    assert "missing.pt" in capsys.readouterr().err


def test_select_without_the_filter_leaves_ties_to_the_first_listed(tmp_path, capsys):
    """With ``--shield off`` the rule is already flown alone: a tie at the top flies nothing more
    and goes to the checkpoint listed first, whichever order they come in."""
    hover, twin = tmp_path / "hover.pt", tmp_path / "twin.pt"
    constant_action_checkpoint(str(hover), 13)
    twin.write_bytes(hover.read_bytes())
    chosen = []
    for order in ((hover, twin), (twin, hover)):
        out = tmp_path / f"sel-{order[0].stem}.json"
        argv = ["select", *map(str, order), "--trials", "1", "--max-steps", "30", "--shield", "off"]
        assert main([*argv, "--no-progress", "--json", str(out)]) == 0
        data = json.loads(out.read_text())
        assert [s["score"] for s in data["scores"]] == [0, 0]  # hovering neither arrives nor crashes
        assert data["tie_break"] is None and all("alone" not in s for s in data["scores"])
        chosen.append(data["chosen"])
    assert chosen == [str(hover), str(twin)]
    assert "tied at" not in capsys.readouterr().out


def test_select_leaves_a_tie_to_the_first_listed_when_a_tied_checkpoint_has_no_filter(tmp_path):
    """``--shield model`` with one checkpoint that records a filter and one that records none: a
    tie at the top is not broken alone (one of them already flew alone), so the first listed wins,
    even where flying both alone would have chosen the other."""
    straight, hover, shipped = tmp_path / "straight.pt", tmp_path / "hover.pt", tmp_path / "straight-f.pt"
    constant_action_checkpoint(str(straight), 4)
    constant_action_checkpoint(str(hover), 13)
    assert main(["ship", "--model", str(straight), "--out", str(shipped), "--shield", "on"]) == 0
    out = tmp_path / "sel.json"
    argv = ["select", str(shipped), str(hover), "--trials", "1", "--max-steps", "30", "--shield", "model"]
    assert main([*argv, "--alone", "--no-progress", "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    # straight behind its filter and hovering alone neither arrive nor crash in 30 steps ...
    assert [s["score"] for s in data["scores"]] == [0, 0]
    # ... and alone straight crashes, so a tie-break alone would have chosen hover
    assert data["scores"][0]["alone"]["score"] < data["scores"][1]["alone"]["score"] == 0
    assert data["tie_break"] is None and data["chosen"] == str(shipped)


def test_select_flies_the_privileged_teacher_in_the_same_flights_as_a_reference(tmp_path, capsys):
    """--teacher: the teacher flies the rule's flights behind the first checkpoint's filter; its
    score is reported beside the candidates', it is never chosen, and each candidate's misses are
    counted among the teacher's."""
    hover = tmp_path / "hover.pt"
    constant_action_checkpoint(str(hover), 13)
    out = tmp_path / "sel.json"
    argv = ["select", str(hover), "--trials", "1", "--max-steps", "75", "--teacher", "--no-progress"]
    assert main([*argv, "--json", str(out)]) == 0
    data = json.loads(out.read_text())
    teacher, (only,) = data["teacher"], data["scores"]
    assert teacher["respects_filter"] is True and teacher["env_of"] == str(hover)
    parts = {k: v for k, v in teacher.items() if isinstance(v, dict)}
    assert {k: v["flights"] for k, v in parts.items()} == {
        "train_seed0": 7, "train_seed1000": 7, "dev_seed0": 8, "dev_seed1": 8,
    }
    assert teacher["goals"] == sum(p["goals"] for p in parts.values())
    assert teacher["score"] == teacher["goals"] - teacher["crashes"]
    assert len(teacher["missed"]) == 30 - teacher["goals"]
    assert teacher["goals"] > only["goals"] == 0  # the teacher plans; the hovering checkpoint never arrives
    assert data["chosen"] == str(hover)  # the reference is never a candidate
    assert len(set(only["missed"])) == 30  # one name per flight: SET_seedS/WORLD/tTRIAL
    assert set(teacher["missed"]) <= set(only["missed"])  # the same names for the same flights
    assert only["missed_by_teacher_too"] == len(teacher["missed"])
    assert "the privileged teacher (a reference)" in capsys.readouterr().out


def test_select_alone_flies_each_checkpoint_without_its_filter_beside_the_rule(tmp_path, capsys):
    """--alone: each checkpoint also flies the rule's flights without its filter; those figures are
    the ones ``--shield off`` gives, and the rule's scores and choice stay as they were."""
    straight, hover = tmp_path / "straight.pt", tmp_path / "hover.pt"
    constant_action_checkpoint(str(straight), 4)
    constant_action_checkpoint(str(hover), 13)
    base = ["select", str(straight), str(hover), "--trials", "1", "--max-steps", "30", "--no-progress"]
    runs = {}
    for name, extra in (("rule", []), ("alone", ["--alone"]), ("off", ["--shield", "off"])):
        out = tmp_path / f"{name}.json"
        assert main([*base, *extra, "--json", str(out)]) == 0
        runs[name] = json.loads(out.read_text())
    assert "alone: score" in capsys.readouterr().out
    scored = zip(runs["alone"]["scores"], runs["rule"]["scores"], runs["off"]["scores"], strict=True)
    for with_alone, rule, off in scored:
        assert {k: v for k, v in with_alone.items() if k != "alone"} == {
            k: v for k, v in rule.items() if k != "alone"
        }  # the rule is untouched
        if "alone" in rule:  # flown alone to break a tie at the top: the same figures
            assert rule["alone"] == with_alone["alone"]
        assert with_alone["alone"] == {k: v for k, v in off.items() if k != "model"}
        assert with_alone["alone"]["score"] == with_alone["alone"]["goals"] - with_alone["alone"]["crashes"]
    assert runs["alone"]["chosen"] == runs["rule"]["chosen"]
    # flying straight ahead, the filter's vetoes change the flights: the two figures differ
    straight_rule = {k: v for k, v in runs["rule"]["scores"][0].items() if k not in ("model", "alone")}
    assert runs["alone"]["scores"][0]["alone"] != straight_rule
