"""Training end to end: a tiny run trains, checkpoints, evaluates, and resumes after a kill."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint
from quadnav_onboard.config import ConfigError, PrimitiveConfig, parse_config
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import PreprocessConfig
from sim_harness.rl.config import TrainConfig
from sim_harness.rl.evaluate import env_config_for_policy, evaluate, policy_greedy_fn, summarize
from sim_harness.rl.train import train
from sim_harness.world import load_world, paper_world_path

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _tiny(tmp_path, **kw) -> TrainConfig:
    base = dict(
        name="tiny",
        seed=3,
        episodes=8,
        train_worlds=(1, 4),
        n_envs=4,
        max_steps=12,
        batch_size=8,
        buffer_size=500,
        learning_starts=16,
        updates_per_step=1.0,
        target_update_interval=5,
        checkpoint_every=4,
        out_dir=str(tmp_path),
    )
    base.update(kw)
    return TrainConfig(**base)


def test_smoke_train_then_evaluate(tmp_path) -> None:
    result = train(_tiny(tmp_path, depth_history=2, double_dqn=True, dueling=True, n_step=2), progress=False)
    run = result.run_dir
    assert run.name.startswith("tiny__seed3__")
    for name in ("config.json", "metrics.csv", "metrics.json", "reward_curve.png", "state.pt", "state.json"):
        assert (run / name).is_file(), name
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["episode"]) for r in rows] == list(range(8))
    assert {r["outcome"] for r in rows} <= {"goal", "crash", "deviation", "timeout"}
    assert all(1 <= int(r["length"]) <= 12 for r in rows)
    assert result.updates > 0 and result.env_steps > 0
    assert json.loads((run / "config.json").read_text())["n_step"] == 2

    policy = Policy.from_path(result.model_path)
    assert policy.depth_history == 2 and policy.network.dueling
    eval_rows = evaluate(
        policy_greedy_fn(policy),
        [load_world(paper_world_path(1))],
        trials=2,
        seed=0,
        env_config=env_config_for_policy(policy, max_steps=10),
    )
    assert len(eval_rows) == 2 and summarize(eval_rows)["trials"] == 2


def test_prioritized_replay_trains_end_to_end_and_changes_what_is_learned(tmp_path) -> None:
    per = train(_tiny(tmp_path / "per", episodes=4, prioritized_replay=True, per_alpha=1.0), progress=False)
    uni = train(_tiny(tmp_path / "uni", episodes=4), progress=False)
    assert per.updates == uni.updates > 0
    assert json.loads((per.run_dir / "config.json").read_text())["prioritized_replay"] is True
    wp = load_checkpoint(per.model_path).model.state_dict()
    wu = load_checkpoint(uni.model_path).model.state_dict()
    assert not all(torch.equal(wp[k], wu[k]) for k in wp)  # same seed: only the replay differs


def test_checkpoint_round_trips_with_its_training_settings(tmp_path) -> None:
    result = train(_tiny(tmp_path, episodes=4), progress=False)
    ckpt = load_checkpoint(result.model_path)
    assert parse_config(PrimitiveConfig, ckpt.primitives, "p") == PrimitiveConfig()
    assert parse_config(PreprocessConfig, ckpt.preprocess, "p") == PreprocessConfig()
    assert ckpt.meta["seed"] == 3
    assert ckpt.meta["train_config"]["episodes"] == 4
    assert ckpt.meta["git_commit"]
    # where the run's numerics came from: a recipe is bit for bit only on the same platform
    plat = ckpt.meta["platform"]
    assert plat["torch"] == torch.__version__ and plat["numpy"] == np.__version__
    assert plat["torch_cpu_capability"] == torch.backends.cpu.get_cpu_capability()
    assert plat["cpu"] and plat["machine"]
    state = torch.load(result.run_dir / "state.pt", weights_only=True)
    for name, tensor in ckpt.model.state_dict().items():
        assert torch.equal(tensor, state["agent"]["q"][name])


def test_resume_after_a_kill_finishes_the_run_without_repeating_episodes(tmp_path) -> None:
    killed = train(_tiny(tmp_path), progress=False, kill_after_episodes=6)
    run = killed.run_dir
    assert not (run / "checkpoints" / "final.pt").exists()
    assert json.loads((run / "state.json").read_text())["episodes"] == 4  # last checkpoint
    resumed = train(resume=run, progress=False)
    assert resumed.run_dir == run and resumed.episodes == 8
    rows = json.loads((run / "metrics.json").read_text())
    assert [r["episode"] for r in rows] == list(range(8))
    assert (run / "checkpoints" / "final.pt").is_file()
    # the schedules continue where they were: late episodes explore less than early ones
    eps = np.array([r["epsilon"] for r in rows])
    assert eps[-1] < eps[0]


def test_training_is_seeded(tmp_path) -> None:
    a = train(_tiny(tmp_path / "a", episodes=4), progress=False)
    b = train(_tiny(tmp_path / "b", episodes=4), progress=False)

    def rows(run):
        return [
            {k: v for k, v in r.items() if k != "wall_s"}
            for r in json.loads((run / "metrics.json").read_text())
        ]

    assert rows(a.run_dir) == rows(b.run_dir)
    wa = load_checkpoint(a.model_path).model.state_dict()
    wb = load_checkpoint(b.model_path).model.state_dict()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_train_command_reports_bad_input_without_a_traceback_or_a_run_dir(tmp_path, capsys) -> None:
    from sim_harness.cli import main

    assert main(["train", "--episodes", "0", "--out-dir", str(tmp_path), "--no-progress"]) == 2
    assert "episodes" in capsys.readouterr().err
    missing = tmp_path / "nope.yaml"
    assert (
        main(["train", "--world-files", str(missing), "--out-dir", str(tmp_path / "runs"), "--no-progress"])
        == 2
    )
    err = capsys.readouterr().err
    assert "nope.yaml" in err and "Traceback" not in err
    assert not (tmp_path / "runs").exists()
    assert main(["train", "--resume", str(tmp_path), "--no-progress"]) == 2
    assert "not a run directory" in capsys.readouterr().err


def test_keep_every_keeps_model_snapshots_that_load(tmp_path) -> None:
    """``keep_every`` leaves one loadable model per N episodes, the last equal to the final one."""
    result = train(_tiny(tmp_path, checkpoint_every=100, keep_every=4), progress=False)
    kept = sorted(p.name for p in (result.run_dir / "checkpoints").glob("ep*.pt"))
    assert kept == ["ep000004.pt", "ep000008.pt"]
    first = load_checkpoint(result.run_dir / "checkpoints" / "ep000004.pt")
    last = load_checkpoint(result.run_dir / "checkpoints" / "ep000008.pt")
    final = load_checkpoint(result.model_path)
    assert first.meta["episodes"] == 4 and last.meta["episodes"] == 8
    for name, tensor in final.model.state_dict().items():
        assert torch.equal(tensor, last.model.state_dict()[name]), name


def test_learning_rate_is_flat_through_the_ramp_then_falls_linearly_to_lr_end(tmp_path) -> None:
    from sim_harness.rl.train import learning_rate_at

    cfg = _tiny(tmp_path, episodes=100, schedule_fraction=0.6, learning_rate=1e-3, lr_end=1e-4)
    assert learning_rate_at(0, cfg) == learning_rate_at(60, cfg) == 1e-3
    assert learning_rate_at(80, cfg) == pytest.approx(5.5e-4)
    assert learning_rate_at(100, cfg) == pytest.approx(1e-4)
    assert learning_rate_at(500, cfg) == pytest.approx(1e-4)
    assert learning_rate_at(99, _tiny(tmp_path, episodes=100, learning_rate=1e-3)) == 1e-3  # lr_end None


def test_lr_end_reaches_the_optimiser(tmp_path) -> None:
    """A tiny run with lr_end: the optimiser's step size at the end lies between lr_end and the start."""
    result = train(_tiny(tmp_path, schedule_fraction=0.25, learning_rate=1e-3, lr_end=1e-5), progress=False)
    state = torch.load(result.run_dir / "state.pt", weights_only=True)
    lr = state["agent"]["optimizer"]["param_groups"][0]["lr"]
    assert 1e-5 <= lr < 1e-3


def test_optional_fields_have_flags_of_their_type() -> None:
    """``--lr-end`` (a ``float | None`` field) parses as a float on the command line."""
    from sim_harness.cli import build_parser
    from sim_harness.rl.config import config_from_args

    args = build_parser().parse_args(["train", "--lr-end", "0.00003", "--episodes", "10"])
    assert config_from_args(args).lr_end == pytest.approx(3e-5)
    assert config_from_args(build_parser().parse_args(["train"])).lr_end is None


def test_training_at_half_scale_records_it_and_eval_flies_it_there(tmp_path) -> None:
    """primitive_scale_m=0.5: the checkpoint holds 0.5 m primitives and the 240-step env; eval flies
    it at 0.5 m with the setpoint slowed to match, without being told."""
    from sim_harness.cli import main

    result = train(_tiny(tmp_path, episodes=4, primitive_scale_m=0.5), progress=False)
    ckpt = load_checkpoint(result.model_path)
    assert ckpt.primitives["scale_m"] == 0.5 and ckpt.meta["env"]["max_steps"] == 24  # 12 written for 1 m
    out = tmp_path / "eval.json"
    argv = ["eval", "--model", str(result.model_path), "--world", "env01", "--trials", "1"]
    assert main([*argv, "--json", str(out), "--no-progress"]) == 0
    data = json.loads(out.read_text())
    assert data["primitive_scale_m"] == 0.5 and data["max_steps"] == 240


def test_episode_outcomes_script_summarises_a_real_run(tmp_path) -> None:
    """scripts/episode_outcomes.py (the figures of docs/results.md on what ε-greedy training sees)
    reads a run's metrics: per world, the episodes in the range and their outcome shares."""
    import subprocess
    import sys
    from pathlib import Path

    result = train(_tiny(tmp_path, episodes=8), progress=False)
    out = tmp_path / "o.json"
    script = Path(__file__).resolve().parents[1] / "scripts" / "episode_outcomes.py"
    subprocess.run([sys.executable, str(script), str(result.run_dir), "--from", "2", "--json", str(out)],
                   check=True, capture_output=True)
    table = json.loads(out.read_text())
    rows = [r for r in json.loads((result.run_dir / "metrics.json").read_text()) if r["episode"] >= 2]
    assert sum(t["episodes"] for t in table.values()) == len(rows) == 6
    for world, t in table.items():
        mine = [r for r in rows if r["world"] == world]
        assert t["crash_share"] == round(sum(r["outcome"] == "crash" for r in mine) / len(mine), 3)
        assert t["mean_progress_m"] == round(sum(r["progress_m"] for r in mine) / len(mine), 2)
    empty = subprocess.run([sys.executable, str(script), str(tmp_path)], capture_output=True, text=True)
    assert empty.returncode == 2 and "no metrics.json" in empty.stderr


def test_reward_floor_reaches_the_training_env_and_the_checkpoint(tmp_path) -> None:
    """``--reward-d-floor-m``: the env trained in divides the shaping reward by at least that distance
    (one step then earns at most R_u / floor), and the checkpoint records it."""
    from sim_harness.env import VecQuadNavEnv
    from sim_harness.rl.train import env_config_for

    cfg = _tiny(tmp_path, reward_d_floor_m=1.0)
    env_cfg = env_config_for(cfg)
    assert env_cfg.reward.d_floor_m == 1.0 and env_config_for(_tiny(tmp_path)).reward.d_floor_m == 0.25
    env = VecQuadNavEnv([load_world(paper_world_path(1))], n_envs=8, seed=0, config=env_cfg)
    env.reset()
    rewards = np.concatenate([env.step(np.full(8, 4))[2] for _ in range(10)])  # straight ahead
    assert rewards.max() <= env_cfg.reward.r_upper / 1.0 + 1e-9 and rewards.max() > 0
    ckpt = load_checkpoint(train(cfg, progress=False).model_path)
    assert ckpt.meta["env"]["reward"]["d_floor_m"] == 1.0


def test_procedural_families_flag_is_validated_and_names_the_key() -> None:
    from sim_harness.cli import build_parser
    from sim_harness.rl.config import config_from_args

    args = build_parser().parse_args(["train", "--procedural-families", "slalom_ud", "clutter", "slalom_ud"])
    assert config_from_args(args).procedural_families == ("slalom_ud", "clutter", "slalom_ud")
    with pytest.raises(ConfigError, match=r"procedural_families.*'forest'"):
        config_from_args(build_parser().parse_args(["train", "--procedural-families", "forest"]))


def test_ctrl_c_saves_the_run_and_says_how_to_resume(tmp_path, capsys, monkeypatch) -> None:
    """Ctrl-C during `quadnav-sim train` is no traceback: the episodes finished are checkpointed,
    the command says how to resume (exit 130), and resuming finishes the run without repeating an
    episode."""
    import sim_harness.rl.train as train_module
    from sim_harness.cli import main
    from sim_harness.env import VecQuadNavEnv

    class CtrlCAtStep20(VecQuadNavEnv):
        steps = 0

        def step(self, actions):
            CtrlCAtStep20.steps += 1
            if CtrlCAtStep20.steps == 20:
                raise KeyboardInterrupt
            return super().step(actions)

    monkeypatch.setattr(train_module, "VecQuadNavEnv", CtrlCAtStep20)
    flags = ["--name", "tiny", "--seed", "3", "--episodes", "40", "--train-worlds", "1", "4", "--n-envs", "4",
             "--max-steps", "12", "--batch-size", "8", "--buffer-size", "500", "--learning-starts", "16",
             "--checkpoint-every", "100", "--out-dir", str(tmp_path), "--no-progress"]
    try:
        rc = main(["train", *flags])
    except KeyboardInterrupt:
        pytest.fail("Ctrl-C escaped `quadnav-sim train` (a traceback, no word of --resume)")
    assert rc == 130
    err = capsys.readouterr().err
    (run,) = tmp_path.iterdir()
    assert "Traceback" not in err and f"resume with: quadnav-sim train --resume {run}" in err
    saved = json.loads((run / "state.json").read_text())["episodes"]
    assert 0 < saved < 40 and f"interrupted after {saved} episodes" in err
    assert (run / "checkpoints" / "latest.pt").is_file() and not (run / "checkpoints" / "final.pt").exists()
    monkeypatch.setattr(train_module, "VecQuadNavEnv", VecQuadNavEnv)
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0
    rows = json.loads((run / "metrics.json").read_text())
    assert [r["episode"] for r in rows] == list(range(40))


def test_ctrl_c_before_the_first_episode_is_a_clean_exit(tmp_path, capsys, monkeypatch) -> None:
    import sim_harness.rl.train as train_module
    from sim_harness.cli import main

    def interrupted(*_args, **_kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(train_module, "VecQuadNavEnv", interrupted)
    try:
        rc = main(["train", "--episodes", "2", "--out-dir", str(tmp_path), "--no-progress"])
    except KeyboardInterrupt:
        pytest.fail("Ctrl-C escaped `quadnav-sim train` as a traceback")
    assert rc == 130
    err = capsys.readouterr().err
    assert "Traceback" not in err and "interrupted before the first episode" in err


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00garbage", b"[1, 2]"])
def test_resume_from_a_corrupt_run_config_is_refused_without_a_traceback(tmp_path, capsys, content) -> None:
    """A config.json of random bytes, an empty one or a list is refused naming it, no traceback."""
    from sim_harness.cli import main

    (tmp_path / "config.json").write_bytes(content)
    assert main(["train", "--resume", str(tmp_path), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and f"{tmp_path / 'config.json'}" in err


def test_the_filters_look_ahead_reaches_the_training_env_and_the_checkpoint(tmp_path) -> None:
    """``--shield-lookahead stop``: the env trained in and the checkpoint's filter look along the
    stop (what eval and the daemon then fly with); an unknown look-ahead is refused by name."""
    from quadnav_onboard.shield import shield_config_from_meta
    from sim_harness.rl.config import load_train_config
    from sim_harness.rl.train import env_config_for

    cfg = _tiny(tmp_path, shield=True, shield_lookahead="stop")
    assert env_config_for(cfg).shield.lookahead == "stop"
    assert env_config_for(_tiny(tmp_path, shield=True)).shield.lookahead == "velocity"
    ckpt = load_checkpoint(train(cfg, progress=False).model_path)
    assert shield_config_from_meta(ckpt.meta).lookahead == "stop"
    with pytest.raises(ConfigError, match=r"shield_lookahead.*'brake'.*velocity, stop"):
        load_train_config({"shield_lookahead": "brake"}, "recipe.yaml")
