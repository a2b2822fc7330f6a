"""DAgger: what it collects, what it aggregates, and that the fit learns the teacher's labels."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import load_checkpoint
from quadnav_onboard.config import ConfigError, PrimitiveConfig
from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent, random_allowed
from sim_harness.rl.config import TrainConfig, load_train_config
from sim_harness.rl.imitation import (
    Aggregate,
    DaggerSettings,
    DaggerTask,
    collect,
    dagger,
    decisive_rows,
    first_choice_agreement,
    fit,
    holding_primitives,
    lr_at,
    margin_loss,
)
from sim_harness.rl.teacher import Teacher, soft_targets
from sim_harness.rl.train import train
from sim_harness.world import parse_world

HOVER = DEFAULT_DIRECTIONS.index((0, 0, 0))
FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))


pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _world():
    return parse_world({
        "name": "open",
        "path": {"waypoints": [[0.0, 0.0, 2.0], [8.0, 0.0, 2.0]], "speed_m_s": 1.0},
        "bounds": {"floor_z": 0.0, "ceiling_z": 4.0},
        "obstacles": [],
    })


class _Hoverer(DQNAgent):
    """A student that always hovers (its greedy action is known)."""

    def greedy(self, depth, rel, allowed=None, scale_m=None):
        return np.full(depth.shape[0], HOVER, dtype=np.int64)


def _spy(monkeypatch, name: str, key: str) -> list[object]:
    """Wrap ``sim_harness.rl.imitation.<name>`` so each call records its keyword ``key`` (the
    real function still runs); returns the list the values are appended to."""
    import sim_harness.rl.imitation as imitation

    seen: list[object] = []
    real = getattr(imitation, name)

    def spy(*args, **kwargs):
        seen.append(kwargs[key])
        return real(*args, **kwargs)

    monkeypatch.setattr(imitation, name, spy)
    return seen


def _env(n: int = 2, max_steps: int = 6) -> VecQuadNavEnv:
    env = VecQuadNavEnv([_world()], n, seed=0, config=EnvConfig(max_steps=max_steps))
    env.reset()
    return env


def test_teacher_iteration_flies_the_teacher_and_labels_every_step() -> None:
    env, teacher = _env(max_steps=12), Teacher()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    counts = collect(env, teacher, _Hoverer(NetworkConfig()), 2, 1.0, np.random.default_rng(0), 0.25, data, 0)
    assert counts == {"goal": 2}  # the teacher flew, not the hovering student
    assert len(data) > 0 and np.all(data.iteration[: len(data)] == 0)
    assert np.all(np.argmax(data.target[: len(data)], axis=1) != HOVER)


def test_student_iteration_flies_the_student_but_keeps_the_teachers_labels() -> None:
    env, teacher = _env(n=2, max_steps=4), Teacher()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    collect(env, teacher, _Hoverer(NetworkConfig()), 2, 1.0, np.random.default_rng(0), 0.25, data, 0)
    first = len(data)
    counts = collect(env, teacher, _Hoverer(NetworkConfig()), 2, 0.0, np.random.default_rng(0), 0.25, data, 1)
    assert counts == {"timeout": 2}  # the student hovered until the step limit
    # aggregated, not replaced: both iterations' rows are there, the second's 2 envs x 4 steps
    assert len(data) == first + 8
    assert list(np.bincount(data.iteration[: len(data)])) == [first, 8]
    # the hovering student's states are labelled with the teacher's move, not its own
    assert np.all(np.argmax(data.target[first: len(data)], axis=1) != HOVER)


def test_aggregate_overwrites_the_oldest_past_capacity() -> None:
    data = Aggregate(5, (1, 2, 2), (1, 3), 3)
    for it in range(3):
        data.add(np.full((2, 1, 2, 2), it, np.float32), np.zeros((2, 1, 3), np.float32),
                 np.full((2, 3), 1 / 3, np.float32), it)
    assert len(data) == 5
    assert sorted(data.iteration.tolist()) == [0, 1, 1, 2, 2]


def test_fit_learns_the_labels(side_rule) -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    agent = DQNAgent(NetworkConfig())
    data = Aggregate(256, (1, 32, 32), (1, 3), 18)
    depth, rel, left = side_rule(rng, 256)
    label = np.where(left, FORWARD, HOVER)  # a rule of the position input
    target = np.full((256, 18), 0.01 / 17, np.float32)
    target[np.arange(256), label] = 0.99
    data.add(depth, rel, target, 0)
    before = np.mean(agent.greedy(depth, rel) == label)
    _, agreement = fit(agent, data, 30.0, 64, rng, torch.optim.Adam(agent.q.parameters(), lr=1e-3))
    after = np.mean(agent.greedy(depth, rel) == label)
    assert after > 0.95 and after > before
    assert agreement > 0.9
    for p, q in zip(agent.q.parameters(), agent.target.parameters(), strict=True):
        assert torch.equal(p, q)


def test_first_choice_agreement_counts_the_rows_whose_arg_max_is_the_teacher_s_and_changes_nothing(
        side_rule) -> None:
    torch.manual_seed(1)
    rng = np.random.default_rng(1)
    agent = DQNAgent(NetworkConfig())
    data = Aggregate(64, (1, 32, 32), (1, 3), 18)
    depth, rel, _ = side_rule(rng, 64)
    data.add(depth, rel, np.zeros((64, 18), np.float32), 0)
    greedy = agent.greedy(depth, rel)
    # the teacher's first choice is the network's own in the even rows and another in the odd
    data.target[np.arange(64), np.where(np.arange(64) % 2 == 0, greedy, (greedy + 1) % 18)] = 1.0
    before = [p.detach().clone() for p in agent.q.parameters()]
    state = rng.bit_generator.state
    assert first_choice_agreement(agent, data, np.arange(64), batch=5) == pytest.approx(0.5)
    assert first_choice_agreement(agent, data, np.arange(0, 64, 2)) == 1.0
    assert first_choice_agreement(agent, data, np.arange(1, 64, 2)) == 0.0
    assert first_choice_agreement(agent, data, np.arange(0)) is None
    assert all(torch.equal(p, q) for p, q in zip(before, agent.q.parameters(), strict=True))
    assert rng.bit_generator.state == state


def test_train_with_imitation_only_writes_the_records_and_a_flyable_model(tmp_path) -> None:
    cfg = TrainConfig(
        name="dg", seed=1, train_worlds=(1,), n_envs=4, max_steps=10, batch_size=16,
        dagger_iterations=2, dagger_episodes=2, imitation_scales=(1.0, 0.5), imitation_only=True,
        imitation_epochs=1.0, teacher_lookahead=1, teacher_grid_m=0.5, out_dir=str(tmp_path),
    )
    result = train(cfg, progress=False)
    records = json.loads((result.run_dir / "dagger.json").read_text())
    assert [(r["iteration"], r["scale_m"]) for r in records] == [(0, 1.0), (0, 0.5), (1, 1.0), (1, 0.5)]
    assert [r["beta"] for r in records] == [1.0, 1.0, 0.5, 0.5]
    assert records[1]["dataset"] < records[3]["dataset"]
    for last in (records[1], records[3]):  # each iteration's last record: the fit and the new states
        assert 0.0 <= last["agreement"] <= 1.0
        assert 0.0 <= last["agreement_new"] <= 1.0
    assert "agreement_new" not in records[0] and "agreement_new" not in records[2]
    ck = load_checkpoint(result.model_path)
    assert ck.meta["train_config"]["dagger_iterations"] == 2
    assert (result.run_dir / "checkpoints" / "imitation.pt").is_file()


def test_fit_by_updates_takes_that_many_steps_whatever_the_aggregates_size() -> None:
    """``imitation_updates``: a fixed number of minibatch steps (a fit whose cost does not grow
    with the aggregate); 0 keeps the passes, whose count grows with it."""
    agent = DQNAgent(NetworkConfig())
    steps: list[int] = []

    class Counting(torch.optim.Adam):
        def step(self, closure=None):
            steps.append(1)
            return super().step(closure)

    for n in (64, 256):
        data = Aggregate(n, (1, 32, 32), (1, 3), 18)
        data.add(np.full((n, 1, 32, 32), 0.5, np.float32), np.zeros((n, 1, 3), np.float32),
                 np.full((n, 18), 1 / 18, np.float32), 0)
        for updates, expected in ((7, 7), (0, 2 * n // 32)):
            steps.clear()
            opt = Counting(agent.q.parameters())
            fit(agent, data, 2.0, 32, np.random.default_rng(0), opt, updates=updates)
            assert len(steps) == expected, (n, updates)


def test_margin_loss_is_zero_only_where_the_experts_action_leads_by_the_margin() -> None:
    q = torch.tensor([[3.0, 1.0, 0.5],    # expert 0 leads by 2 >= 1: no loss
                      [3.0, 2.5, 0.0],    # expert 0 leads by 0.5: 1 + 2.5 - 3
                      [3.0, 2.5, 0.0]])   # expert 2 trails: 1 + 3 - 0
    expert = torch.tensor([0, 0, 2])
    per_row = [float(margin_loss(q[i:i + 1], expert[i:i + 1], 1.0)) for i in range(3)]
    assert per_row == pytest.approx([0.0, 0.5, 4.0])
    assert float(margin_loss(q, expert, 1.0)) == pytest.approx(4.5 / 3)


def test_the_margin_term_makes_the_huber_fit_separate_the_first_choice(side_rule) -> None:
    """Huber labels whose first choice leads by only 0.05: the fit alone gets the values near
    but leaves the order to chance; with the margin term the first choice leads by about the
    margin."""
    rng = np.random.default_rng(0)
    n = 256
    depth, rel, left = side_rule(rng, n)
    best = np.where(left, FORWARD, HOVER)
    target = np.ones((n, 18), np.float32)
    target[np.arange(n), best] = 1.05
    data = Aggregate(n, (1, 32, 32), (1, 3), 18)
    data.add(depth, rel, target, 0)
    leads = {}
    for weight in (0.0, 1.0):
        torch.manual_seed(0)
        agent = DQNAgent(NetworkConfig())
        opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
        fit(agent, data, 30.0, 64, np.random.default_rng(0), opt, "huber", margin_weight=weight, margin=0.5)
        with torch.no_grad():
            q = agent.q(torch.as_tensor(depth), torch.as_tensor(rel)).numpy()
        others = np.where(np.arange(18)[None, :] == best[:, None], -np.inf, q).max(axis=1)
        leads[weight] = q[np.arange(n), best] - others
    assert np.median(leads[1.0]) > 0.3 and np.all(leads[1.0] > 0)
    assert np.median(leads[0.0]) < 0.1
    with pytest.raises(ValueError, match="margin"):
        fit(agent, data, 1.0, 64, rng, opt, "huber", margin_weight=-1.0)


def test_the_fits_step_size_falls_geometrically_to_its_end_value() -> None:
    base = dict(iterations=5, episodes=1, beta=0.5, epochs=1.0, lr=1e-3, temperature_m=0.1,
                batch_size=8, buffer=8, seed=0)
    flat = DaggerSettings(**base)
    falling = DaggerSettings(**base, lr_end=1e-5)
    assert [lr_at(flat, i) for i in range(5)] == [1e-3] * 5
    assert [lr_at(falling, i) for i in range(5)] == pytest.approx([1e-3, 10**-3.5, 1e-4, 10**-4.5, 1e-5])


def test_random_allowed_draws_every_allowed_primitive_and_nothing_else() -> None:
    allowed = np.zeros((2, 18), dtype=bool)
    allowed[0, [2, 5]] = True
    allowed[1] = True
    rng = np.random.default_rng(0)
    picks = np.stack([random_allowed(allowed, rng) for _ in range(400)])
    assert picks.dtype == np.int64
    assert set(picks[:, 0]) == {2, 5}  # both allowed ones, nothing else
    assert len(set(picks[:, 1])) == 18  # every primitive where all are allowed


def test_noise_off_draws_no_random_number() -> None:
    env, teacher = _env(max_steps=4), Teacher()
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    rng = np.random.default_rng(0)
    before = rng.bit_generator.state
    collect(env, teacher, _Hoverer(NetworkConfig()), 2, 1.0, rng, 0.25, data, 0, noise=0.0)
    assert rng.bit_generator.state == before  # the teacher flew, nothing drawn
    collect(env, teacher, _Hoverer(NetworkConfig()), 2, 1.0, rng, 0.25, data, 0, noise=0.5)
    assert rng.bit_generator.state != before


def test_noise_flies_random_primitives_and_keeps_the_teachers_labels() -> None:
    env, teacher = _env(n=4, max_steps=6), Teacher()
    flown: list[np.ndarray] = []
    step = env.step
    env.step = lambda actions: (flown.append(np.array(actions)), step(actions))[1]  # type: ignore[method-assign]
    data = Aggregate(1000, (1, 32, 32), (1, 3), 18)
    counts = collect(env, teacher, _Hoverer(NetworkConfig()), 4, 0.0, np.random.default_rng(0), 0.25, data, 1,
                     noise=1.0)
    assert sum(counts.values()) == 4
    actions = np.concatenate(flown)
    # the hovering student chose every step, and every step flew a random primitive instead
    assert np.mean(actions == HOVER) < 0.2 and len(set(actions.tolist())) > 9
    # the states are labelled with the teacher's move
    assert np.all(np.argmax(data.target[: len(data)], axis=1) != HOVER)


@pytest.mark.parametrize("noise", [-0.1, 1.5, float("nan")])
def test_noise_outside_a_probability_is_refused(noise: float) -> None:
    env, teacher = _env(), Teacher()
    data = Aggregate(100, (1, 32, 32), (1, 3), 18)
    with pytest.raises(ValueError, match="noise"):
        collect(env, teacher, _Hoverer(NetworkConfig()), 1, 1.0, np.random.default_rng(0), 0.25, data, 0,
                noise=noise)


def test_dagger_noise_is_range_checked_in_the_config() -> None:
    with pytest.raises(ConfigError, match=r"recipe\.yaml.*dagger_noise.*1\.5"):
        load_train_config({"dagger_noise": 1.5}, "recipe.yaml")
    assert load_train_config({"dagger_noise": 0.1}, "recipe.yaml").dagger_noise == 0.1


def test_a_tasks_own_noise_overrides_the_settings_noise(monkeypatch) -> None:
    seen = _spy(monkeypatch, "collect", "noise")
    settings = DaggerSettings(iterations=1, episodes=2, beta=1.0, epochs=1.0, lr=1e-3, temperature_m=0.25,
                              batch_size=8, buffer=200, seed=0, noise=0.3)
    tasks = [
        DaggerTask(EnvConfig(max_steps=4), [_world()], Teacher()),  # the settings' noise
        DaggerTask(EnvConfig(max_steps=4), [_world()], Teacher(), noise=0.0),  # its own
    ]
    records = dagger(DQNAgent(NetworkConfig()), tasks, settings, n_envs=2)
    assert seen == [0.3, 0.0]
    assert [r["noise"] for r in records] == [0.3, 0.0]  # dagger.json says what each task flew with


def test_lab_dagger_noise_is_range_checked_and_needs_the_lab_layouts() -> None:
    with pytest.raises(ConfigError, match=r"recipe\.yaml.*lab_dagger_noise.*-0\.1"):
        load_train_config({"lab_dagger_noise": -0.1}, "recipe.yaml")
    with pytest.raises(ConfigError, match=r"recipe\.yaml.*'lab_dagger_noise'.*set lab_layouts"):
        load_train_config({"lab_dagger_noise": 0.0, "dagger_iterations": 1}, "recipe.yaml")


def test_decisive_rows_are_those_whose_first_choice_leads_the_second_by_the_ratio() -> None:
    """Soft targets softmax(-cost / T) with T = 0.25: a first choice 0.5 m cheaper than the second
    has log ratio 2, one 0.05 m cheaper 0.2; a row of exact ties has 0."""
    temperature = 0.25
    costs = np.array([[0.0, 0.5, 1.0], [0.0, 0.05, 3.0], [0.2, 0.2, 0.2]])
    target = torch.as_tensor(soft_targets(costs, temperature))
    assert decisive_rows(target, 0.3 / temperature).tolist() == [True, False, False]
    assert decisive_rows(target, 0.04 / temperature).tolist() == [True, True, False]
    one_hot = torch.tensor([[1.0, 0.0, 0.0]])  # the second choice's probability underflowed to 0
    assert decisive_rows(one_hot, 50.0).tolist() == [True]


def test_the_margin_loss_counts_only_the_given_rows_in_its_batch_mean() -> None:
    q = torch.tensor([[2.0, 0.0, 0.0], [0.5, 0.0, 0.0], [0.0, 1.0, 3.0]])
    expert = torch.tensor([0, 0, 2])
    rows = torch.tensor([True, False, True])
    assert float(margin_loss(q, expert, 1.0, rows)) == pytest.approx((0.0 + 0.0 + 0.0) / 3)
    assert float(margin_loss(q, torch.tensor([0, 0, 1]), 1.0, rows)) == pytest.approx(3.0 / 3)
    assert float(margin_loss(q, expert, 1.0, torch.tensor([False, True, False]))) == pytest.approx(0.5 / 3)


def test_the_gated_margin_leaves_near_ties_to_the_soft_targets(side_rule) -> None:
    """Targets whose first choice is 0.03 m of cost cheaper than the second (T = 0.3): with the
    margin limited to a 0.1 m gap no row is decisive, so the fit is the soft targets' fit alone,
    weight for weight; the margin in every state changes it."""
    rng = np.random.default_rng(0)
    n = 64
    depth, rel, _ = side_rule(rng, n)
    costs = np.full((n, 18), 2.0)
    costs[:, HOVER], costs[:, FORWARD] = 0.0, 0.03
    temperature = 0.3
    data = Aggregate(n, (1, 32, 32), (1, 3), 18)
    data.add(depth, rel, soft_targets(costs, temperature), 0)
    weights = {}
    for name, margin_weight, ratio in (("none", 0.0, 0.0), ("gated", 1.0, 0.1 / temperature),
                                       ("everywhere", 1.0, 0.0)):
        torch.manual_seed(0)
        agent = DQNAgent(NetworkConfig())
        opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
        fit(agent, data, 2.0, 32, np.random.default_rng(0), opt, "cross_entropy", margin_weight=margin_weight,
            margin=1.0, margin_min_log_ratio=ratio)
        weights[name] = torch.cat([p.detach().flatten() for p in agent.q.parameters()])
    assert torch.equal(weights["gated"], weights["none"])
    assert not torch.allclose(weights["everywhere"], weights["none"])


def test_the_gated_margin_needs_the_cross_entropy_fit_and_a_non_negative_ratio(side_rule) -> None:
    depth, rel, _ = side_rule(np.random.default_rng(0), 8)
    data = Aggregate(8, (1, 32, 32), (1, 3), 18)
    data.add(depth, rel, np.full((8, 18), 1 / 18, np.float32), 0)
    agent = DQNAgent(NetworkConfig())
    opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
    with pytest.raises(ValueError, match="cross-entropy"):
        fit(agent, data, 1.0, 8, np.random.default_rng(0), opt, "huber", margin_weight=1.0,
            margin_min_log_ratio=1.0)
    with pytest.raises(ValueError, match="margin_min_log_ratio"):
        fit(agent, data, 1.0, 8, np.random.default_rng(0), opt, margin_weight=1.0, margin_min_log_ratio=-1.0)


def test_dagger_passes_the_margins_least_gap_to_the_fit_as_a_log_ratio(monkeypatch) -> None:
    seen = _spy(monkeypatch, "fit", "margin_min_log_ratio")
    settings = DaggerSettings(iterations=1, episodes=2, beta=1.0, epochs=1.0, lr=1e-3, temperature_m=0.25,
                              batch_size=8, buffer=200, seed=0, margin_weight=1.0, margin_min_gap_m=0.1)
    dagger(DQNAgent(NetworkConfig()), [DaggerTask(EnvConfig(max_steps=4), [_world()], Teacher())],
           settings, n_envs=2)
    assert seen == [pytest.approx(0.4)]


def test_dagger_refuses_the_margins_least_gap_with_a_huber_teacher_before_it_flies(monkeypatch) -> None:
    import sim_harness.rl.imitation as imitation

    class HuberTeacher(Teacher):
        loss = "huber"

    flown: list[int] = []
    monkeypatch.setattr(imitation, "collect", lambda *args, **kwargs: flown.append(1))
    settings = DaggerSettings(iterations=1, episodes=2, beta=1.0, epochs=1.0, lr=1e-3, temperature_m=0.25,
                              batch_size=8, buffer=200, seed=0, margin_weight=1.0, margin_min_gap_m=0.1)
    with pytest.raises(ValueError, match=r"margin_min_gap_m.*'huber'"):
        dagger(DQNAgent(NetworkConfig()), [DaggerTask(EnvConfig(max_steps=4), [_world()], HuberTeacher())],
               settings, n_envs=2)
    assert flown == []


def test_imitation_margin_min_gap_is_range_checked_and_needs_the_margin_and_the_privileged_teacher() -> None:
    key = "imitation_margin_min_gap_m"
    with pytest.raises(ConfigError, match=rf"recipe\.yaml.*{key}.*-0\.1"):
        load_train_config({key: -0.1}, "recipe.yaml")
    with pytest.raises(ConfigError, match=rf"recipe\.yaml.*'{key}'.*imitation_margin_weight > 0"):
        load_train_config({key: 0.1, "dagger_iterations": 1}, "recipe.yaml")
    with pytest.raises(ConfigError, match=rf"'{key}'.*imitation_teacher: privileged"):
        load_train_config({key: 0.1, "imitation_margin_weight": 1.0, "imitation_teacher": "filter",
                           "init_model": "m.pt", "shield": True}, "recipe.yaml")
    cfg = load_train_config({key: 0.1, "imitation_margin_weight": 1.0}, "recipe.yaml")
    assert cfg.imitation_margin_min_gap_m == 0.1


def test_the_holding_primitives_are_the_nine_without_a_forward_step() -> None:
    holding = holding_primitives(PrimitiveConfig())
    assert holding.shape == (18,) and int(holding.sum()) == 9
    assert holding[HOVER] and not holding[FORWARD]
    assert all(holding[i] == (d[0] == 0) for i, d in enumerate(DEFAULT_DIRECTIONS))


def test_the_margin_against_some_primitives_leaves_the_others_free() -> None:
    q = torch.tensor([[2.0, 2.5, 1.5], [2.0, 0.0, 3.0]])
    expert = torch.tensor([0, 0])
    against = torch.tensor([False, False, True])
    # row 0: the free primitive 1 leads the expert's and costs nothing; primitive 2 is 0.5 short of
    # the margin. Row 1: primitive 2 leads the expert's by 1, plus the margin.
    assert float(margin_loss(q[:1], expert[:1], 1.0, against=against)) == pytest.approx(0.5)
    assert float(margin_loss(q[1:], expert[1:], 1.0, against=against)) == pytest.approx(2.0)
    assert float(margin_loss(q[:1], expert[:1], 1.0)) == pytest.approx(1.5)  # every other: primitive 1


def test_the_holding_margin_acts_only_where_the_teacher_goes_forward(side_rule) -> None:
    """Targets whose first choice is hovering: the margin against the holding primitives has no
    row to act in, so the fit is the soft targets' fit alone, weight for weight; with the first
    choice forward it changes the fit and puts forward further ahead of every holding primitive."""
    rng = np.random.default_rng(0)
    n = 64
    depth, rel, _ = side_rule(rng, n)
    against = holding_primitives(PrimitiveConfig())
    weights, lead = {}, {}
    for first in (HOVER, FORWARD):
        costs = np.full((n, 18), 2.0)
        costs[:, first] = 0.0
        data = Aggregate(n, (1, 32, 32), (1, 3), 18)
        data.add(depth, rel, soft_targets(costs, 1.0), 0)
        for name, margin_weight, margin_against in (("none", 0.0, None), ("holding", 1.0, against)):
            torch.manual_seed(0)
            agent = DQNAgent(NetworkConfig())
            opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
            fit(agent, data, 25.0, 32, np.random.default_rng(0), opt, "cross_entropy",
                margin_weight=margin_weight, margin=1.0, margin_against=margin_against)
            weights[first, name] = torch.cat([p.detach().flatten() for p in agent.q.parameters()])
            with torch.no_grad():
                q = agent.q(agent._t(depth.astype(np.float32)), agent._t(rel)).numpy()
            lead[first, name] = float(np.median(q[:, FORWARD] - q[:, against].max(axis=1)))
    assert torch.equal(weights[HOVER, "holding"], weights[HOVER, "none"])
    assert not torch.allclose(weights[FORWARD, "holding"], weights[FORWARD, "none"])
    assert lead[FORWARD, "holding"] > lead[FORWARD, "none"] + 0.15, lead


def test_the_margin_against_nothing_is_refused(side_rule) -> None:
    depth, rel, _ = side_rule(np.random.default_rng(0), 8)
    data = Aggregate(8, (1, 32, 32), (1, 3), 18)
    data.add(depth, rel, np.full((8, 18), 1 / 18, np.float32), 0)
    agent = DQNAgent(NetworkConfig())
    opt = torch.optim.Adam(agent.q.parameters(), lr=1e-3)
    for bad in (np.zeros(18, bool), np.ones(17, bool)):
        with pytest.raises(ValueError, match="margin_against"):
            fit(agent, data, 1.0, 8, np.random.default_rng(0), opt, margin_weight=1.0, margin_against=bad)


def test_dagger_holds_the_margin_against_the_holding_primitives_when_told(monkeypatch) -> None:
    seen = _spy(monkeypatch, "fit", "margin_against")
    for holding in (False, True):
        settings = DaggerSettings(iterations=1, episodes=2, beta=1.0, epochs=1.0, lr=1e-3, temperature_m=0.25,
                                  batch_size=8, buffer=200, seed=0, margin_weight=1.0,
                                  margin_against_holding=holding)
        dagger(DQNAgent(NetworkConfig()), [DaggerTask(EnvConfig(max_steps=4), [_world()], Teacher())],
               settings, n_envs=2)
    assert seen[0] is None
    assert np.array_equal(seen[1], holding_primitives(PrimitiveConfig()))


def test_imitation_margin_against_is_checked_and_needs_the_margin() -> None:
    key = "imitation_margin_against"
    with pytest.raises(ConfigError, match=rf"recipe\.yaml.*{key}"):
        load_train_config({key: "forward"}, "recipe.yaml")
    with pytest.raises(ConfigError, match=rf"recipe\.yaml.*'{key}'.*imitation_margin_weight > 0"):
        load_train_config({key: "holding"}, "recipe.yaml")
    cfg = load_train_config({key: "holding", "imitation_margin_weight": 1.0}, "recipe.yaml")
    assert cfg.imitation_margin_against == "holding"
