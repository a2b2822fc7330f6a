"""Schedules, replay buffer, n-step returns and the DQN update."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quadnav_onboard.network import NetworkConfig
from sim_harness.rl.agent import AgentConfig, DQNAgent
from sim_harness.rl.replay import NStepAccumulator, PrioritizedReplayBuffer, ReplayBuffer
from sim_harness.rl.schedules import LinearSchedule, linear_schedule

pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.mark.parametrize(("start", "end"), [(1.0, 0.1), (0.01, 0.99)])
def test_schedules_hit_their_end_points_at_80_percent_and_stay_flat(start: float, end: float) -> None:
    sched = LinearSchedule(start, end, total_episodes=2000, fraction=0.8)
    assert sched(0) == pytest.approx(start)
    assert sched(1600) == pytest.approx(end)
    assert sched(800) == pytest.approx((start + end) / 2)
    assert all(sched(e) == pytest.approx(end) for e in (1601, 1800, 1999, 2500))
    values = [sched(e) for e in range(0, 1601)]
    diffs = np.diff(values)
    assert np.all(diffs < 0) if end < start else np.all(diffs > 0)  # strictly monotone ramp


def test_schedule_rejects_bad_arguments() -> None:
    with pytest.raises(ValueError):
        linear_schedule(1.0, 0.1, 0, 0, 0.8)
    with pytest.raises(ValueError):
        linear_schedule(1.0, 0.1, 0, 10, 0.0)


def _transitions(m: int, offset: int = 0) -> dict[str, np.ndarray]:
    i = np.arange(offset, offset + m)
    return {
        "depth": np.broadcast_to((i % 97 / 100.0)[:, None, None, None], (m, 1, 32, 32)).astype(np.float32),
        "rel": np.stack([i, -i, 2 * i], axis=1)[:, None, :].astype(np.float32),
        "action": i % 18,
        "reward": i.astype(np.float32) * 0.5,
        "next_depth": np.ones((m, 1, 32, 32), np.float32),
        "next_rel": np.stack([i + 1, i, i], axis=1)[:, None, :].astype(np.float32),
        "done": (i % 2).astype(np.float32),
    }


def test_replay_samples_exactly_what_was_stored() -> None:
    buf = ReplayBuffer(100, (1, 32, 32), (1, 3), seed=0)
    buf.add(**_transitions(40))
    batch = buf.sample(256)
    i = batch.rel[:, 0, 0].astype(int)  # the transition id we encoded
    assert set(i.tolist()) <= set(range(40))
    np.testing.assert_array_equal(batch.rel[:, 0], np.stack([i, -i, 2 * i], axis=1))
    np.testing.assert_array_equal(batch.action, i % 18)
    np.testing.assert_array_equal(batch.reward, i * 0.5)
    np.testing.assert_array_equal(batch.done, i % 2)
    np.testing.assert_allclose(batch.depth[:, 0, 5, 5], i % 97 / 100.0, atol=1e-3)  # float16 storage
    np.testing.assert_array_equal(batch.next_rel[:, 0, 0], i + 1)
    assert len(set(i.tolist())) > 30  # uniform over what is there


def test_replay_ring_overwrites_the_oldest() -> None:
    buf = ReplayBuffer(50, (1, 32, 32), (1, 3), seed=1)
    for k in range(4):
        buf.add(**_transitions(20, offset=20 * k))
    assert len(buf) == 50
    ids = set(buf.sample(2000).rel[:, 0, 0].astype(int).tolist())
    assert ids == set(range(30, 80))


def test_replay_sampling_is_seeded() -> None:
    a, b = (ReplayBuffer(100, (1, 32, 32), (1, 3), seed=5) for _ in range(2))
    for buf in (a, b):
        buf.add(**_transitions(60))
    np.testing.assert_array_equal(a.sample(32).index, b.sample(32).index)


def test_nstep_accumulates_discounted_returns_and_flushes_at_episode_end() -> None:
    acc = NStepAccumulator(n_envs=1, n_step=3)
    gamma = 0.5
    z = np.zeros((1, 1, 32, 32), np.float32)
    outs = []
    for t in range(5):
        rel = np.full((1, 1, 3), t, np.float32)
        nxt = np.full((1, 1, 3), t + 1, np.float32)
        end = np.array([t == 4])
        outs.append(acc.push(z, rel, np.array([t]), np.array([1.0]), z, nxt, end, np.array([False]), gamma))
    assert outs[0] == {} and outs[1] == {}
    assert outs[2]["reward"].tolist() == [1.75] and outs[2]["n"].tolist() == [3]
    assert outs[2]["next_rel"][0, 0, 0] == 3 and outs[2]["action"].tolist() == [0]
    last = outs[4]  # t=2 (3-step), t=3 (2-step), t=4 (1-step), all terminal
    assert last["action"].tolist() == [2, 3, 4]
    assert last["reward"].tolist() == [1.75, 1.5, 1.0]
    assert last["n"].tolist() == [3, 2, 1]
    assert last["done"].tolist() == [1.0, 1.0, 1.0]


def test_dqn_update_moves_q_towards_the_target() -> None:
    torch.manual_seed(0)
    agent = DQNAgent(NetworkConfig(), AgentConfig(learning_rate=1e-3, target_update_interval=10_000))
    buf = ReplayBuffer(16, (1, 32, 32), (1, 3), seed=0)
    t = _transitions(16)
    t["done"] = np.ones(16, np.float32)  # terminal: target = reward
    t["reward"] = np.full(16, 2.0, np.float32)
    buf.add(**t)
    batch = buf.sample(16)
    first = agent.update(batch, gamma=0.99)
    for _ in range(100):
        last = agent.update(batch, gamma=0.99)
    assert last < first * 0.1
    with torch.no_grad():
        q = agent.q(torch.as_tensor(batch.depth), torch.as_tensor(batch.rel))
    q_sa = q.gather(1, torch.as_tensor(batch.action)[:, None]).squeeze(1)
    assert torch.allclose(q_sa, torch.full_like(q_sa, 2.0), atol=0.3)


def test_epsilon_one_is_uniform_and_zero_is_greedy() -> None:
    torch.manual_seed(0)
    agent = DQNAgent(NetworkConfig())
    rng = np.random.default_rng(0)
    depth = np.ones((300, 1, 32, 32), np.float32)
    rel = np.zeros((300, 1, 3), np.float32)
    greedy = agent.act(depth, rel, 0.0, rng)
    assert len(set(greedy.tolist())) == 1
    random = agent.act(depth, rel, 1.0, rng)
    assert len(set(random.tolist())) == 18


def test_prioritized_replay_samples_in_proportion_to_priority() -> None:
    """P(i) = p_i^α / Σ p^α: with α = 1 and |TD errors| 1 and 3, the second is drawn 3 times as
    often, and its importance weight (N P)^-β is the smaller one (the largest weight is 1)."""
    buf = PrioritizedReplayBuffer(10, (1, 32, 32), (1, 3), seed=0, alpha=1.0, eps=1e-9)
    idx = buf.add(**_transitions(2))
    buf.update_priorities(idx, np.array([1.0, 3.0]))
    buf.beta = 1.0
    batch = buf.sample(40_000)
    share = (batch.rel[:, 0, 0] == 1).mean()
    assert abs(share - 0.75) < 0.01
    w = {int(i): float(wi) for i, wi in zip(batch.rel[:, 0, 0], batch.weight, strict=True)}
    # weights (N P)^-β normalised by the largest: (2 * 3/4)^-1 / (2 * 1/4)^-1 = 1/3
    assert w[0] == pytest.approx(1.0) and w[1] == pytest.approx(1 / 3, rel=1e-5)


def test_prioritized_replay_new_transitions_get_the_largest_priority_and_alpha_0_is_uniform() -> None:
    buf = PrioritizedReplayBuffer(10, (1, 32, 32), (1, 3), seed=1, alpha=0.6)
    first = buf.add(**_transitions(2))
    buf.update_priorities(first, np.array([5.0, 0.0]))
    new = buf.add(**_transitions(1, offset=2))
    assert buf.priority[new[0]] == pytest.approx(buf.priority[first[0]])  # max so far, not the default 1
    assert buf.priority[first[1]] < buf.priority[first[0]]
    flat = PrioritizedReplayBuffer(10, (1, 32, 32), (1, 3), seed=2, alpha=0.0)
    flat.update_priorities(flat.add(**_transitions(4)), np.array([0.0, 1.0, 10.0, 100.0]))
    counts = np.bincount(flat.sample(40_000).rel[:, 0, 0].astype(int), minlength=4) / 40_000
    np.testing.assert_allclose(counts, 0.25, atol=0.01)
    with pytest.raises(ValueError, match="alpha"):
        PrioritizedReplayBuffer(10, (1, 32, 32), (1, 3), seed=0, alpha=-1.0)


def test_weighted_update_ignores_zero_weight_samples_and_reports_td_errors() -> None:
    """A sample of weight 0 contributes no gradient: the update equals one on the other samples."""
    t = _transitions(4)
    t["done"] = np.ones(4, np.float32)
    buf = ReplayBuffer(4, (1, 32, 32), (1, 3), seed=0)
    buf.add(**t)
    full = buf._batch(np.arange(4))
    agents = []
    for _ in range(2):
        torch.manual_seed(0)
        agents.append(DQNAgent(NetworkConfig(), AgentConfig(target_update_interval=10_000)))
    full.weight = np.array([1.0, 1.0, 1.0, 0.0], np.float32)
    part = buf._batch(np.arange(3))
    part.weight = np.full(3, 0.75, np.float32)  # the mean runs over 4 samples there, 3 here
    assert agents[0].update(full, gamma=0.9) == pytest.approx(agents[1].update(part, gamma=0.9), rel=1e-5)
    for a, b in zip(agents[0].q.parameters(), agents[1].q.parameters(), strict=True):
        torch.testing.assert_close(a, b)
    assert agents[0].last_td_abs.shape == (4,) and (agents[0].last_td_abs > 0).all()


# -- the run's logs: evaluations during training, TensorBoard, hooks ------------------------------
def _tiny_config(out_dir, **kw):
    from sim_harness.rl.config import TrainConfig

    base = dict(
        name="tiny", seed=3, episodes=12, train_worlds=(1, 4), n_envs=4, max_steps=12, batch_size=8,
        buffer_size=500, learning_starts=16, target_update_interval=5, checkpoint_every=4,
        out_dir=str(out_dir),
    )  # fmt: skip
    base.update(kw)
    return TrainConfig(**base)


def _rows(run_dir) -> list[dict]:
    import json

    rows = json.loads((run_dir / "metrics.json").read_text())
    return [{k: v for k, v in r.items() if k != "wall_s"} for r in rows]


class _Seen:
    """A TrainHook that keeps what it is told."""

    def __init__(self) -> None:
        self.episodes: list[int] = []
        self.evaluations: list[tuple[int, dict, bool]] = []

    def on_episode(self, row: dict) -> None:
        self.episodes.append(row["episode"])

    def on_evaluation(self, episode: int, scores: dict, model_path, run_dir) -> None:
        self.evaluations.append((episode, scores, model_path.is_file()))


def test_evaluations_during_training_leave_the_training_itself_unchanged(tmp_path) -> None:
    """Same seed with and without eval_every: the same episodes, losses and final weights; the
    evaluations are written every 6 episodes and at the end, and the hooks see each of them."""
    import json

    from quadnav_onboard.checkpoint import load_checkpoint
    from sim_harness.rl.train import train

    plain = train(_tiny_config(tmp_path / "a", tensorboard=False), progress=False)
    seen = _Seen()
    evald = train(_tiny_config(tmp_path / "b", eval_every=6, eval_trials=1), progress=False, hooks=[seen])
    assert _rows(plain.run_dir) == _rows(evald.run_dir)
    wa = load_checkpoint(plain.model_path).model.state_dict()
    wb = load_checkpoint(evald.model_path).model.state_dict()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)
    evals = json.loads((evald.run_dir / "evals.json").read_text())
    assert [e["episode"] for e in evals] == [6, 12]
    assert all(0.0 <= e["goal_rate"] <= 1.0 and 0.0 <= e["collision_free_rate"] <= 1.0 for e in evals)
    assert (evald.run_dir / "evals.csv").read_text().splitlines()[0].startswith("episode,env_steps,goal_rate")
    assert seen.episodes == list(range(12))
    assert [(e, ok) for e, _, ok in seen.evaluations] == [(6, True), (12, True)]
    assert not (plain.run_dir / "evals.json").exists() and not (plain.run_dir / "tb").exists()


def test_tensorboard_files_hold_the_runs_curves(tmp_path) -> None:
    """Reward, length, outcome rates, ε, γ, loss and the evaluation scores, one point per episode
    (per evaluation for the scores), beside the run's metrics CSV and JSON."""
    ea = pytest.importorskip(
        "tensorboard.backend.event_processing.event_accumulator",
        reason='the tensorboard extra is not installed (pip install "quadnav[tensorboard]")',
    )
    from sim_harness.rl.train import train

    result = train(_tiny_config(tmp_path, eval_every=6, eval_trials=1), progress=False)
    acc = ea.EventAccumulator(str(result.run_dir / "tb"))
    acc.Reload()
    tags = set(acc.Tags()["scalars"])
    per_episode = {"episode/reward", "episode/length", "schedule/epsilon", "schedule/gamma",
                   "outcome/goal", "outcome/crash", "outcome/deviation", "outcome/timeout"}  # fmt: skip
    assert per_episode | {"train/loss", "eval/goal_rate", "eval/collision_free_rate"} <= tags
    rewards = [e.value for e in acc.Scalars("episode/reward")]
    assert rewards == pytest.approx([r["reward"] for r in _rows(result.run_dir)], abs=1e-5)
    assert [e.step for e in acc.Scalars("eval/goal_rate")] == [6, 12]
    last_rates = [acc.Scalars(f"outcome/{o}")[-1].value for o in ("goal", "crash", "deviation", "timeout")]
    assert sum(last_rates) == pytest.approx(1.0)
    assert (result.run_dir / "metrics.csv").is_file() and (result.run_dir / "metrics.json").is_file()


def test_without_tensorboard_the_run_goes_on_and_writes_its_metrics(tmp_path, monkeypatch) -> None:
    import builtins

    from sim_harness.rl import tblog
    from sim_harness.rl.train import train

    real_import = builtins.__import__

    def no_tensorboard(name: str, *args, **kwargs):
        if name.startswith("torch.utils.tensorboard") or name.startswith("tensorboard"):
            raise ImportError(f"No module named {name!r}")
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(builtins, "__import__", no_tensorboard)
    monkeypatch.setattr(tblog, "_warned", False)
    assert not tblog.tensorboard_available()
    result = train(_tiny_config(tmp_path, episodes=4), progress=False)
    assert not (result.run_dir / "tb").exists() and len(_rows(result.run_dir)) == 4


def test_limit_threads_holds_torch_and_numba_to_the_counts_asked() -> None:
    import numba

    from sim_harness.rl.threads import limit_threads

    before = numba.get_num_threads()
    try:
        counts = limit_threads(1, 1)
        assert (counts.torch, counts.numba) == (1, 1) == (torch.get_num_threads(), numba.get_num_threads())
    finally:
        numba.set_num_threads(before)
