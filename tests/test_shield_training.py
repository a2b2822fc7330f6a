"""The shield in the loop: the env's allowed set, shielded acting, masked TD targets, and a
shielded checkpoint flying the same shield in evaluation."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.policy import Policy, masked_argmax
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS
from quadnav_onboard.reward import RewardParams
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent
from sim_harness.rl.config import TrainConfig
from sim_harness.rl.evaluate import env_config_for_policy, evaluate, policy_greedy_fn
from sim_harness.rl.replay import Batch, NStepAccumulator, ReplayBuffer
from sim_harness.rl.train import train
from sim_harness.world import parse_world

FORWARD = DEFAULT_DIRECTIONS.index((1, 0, 0))
HOVER = DEFAULT_DIRECTIONS.index((0, 0, 0))
SHIELDED = EnvConfig(start_jitter_m=0.0, max_steps=30, shield=ShieldConfig(enabled=True))


def _world(obstacles: list) -> object:
    return parse_world(
        {"name": "w", "path": {"waypoints": [[0, 0, 2], [12, 0, 2]]}, "obstacles": obstacles}, "test"
    )


WALL = [{"type": "box", "center": [1.6, 0, 2], "size": [0.2, 20, 20]}]


def test_env_vetoes_forward_primitives_into_a_wall():
    env = VecQuadNavEnv([_world(WALL)], 2, seed=0, config=SHIELDED)
    env.reset()
    assert not env.allowed[:, FORWARD].any()
    assert env.allowed[:, HOVER].all()


def test_knowing_each_worlds_band_the_filter_vetoes_primitives_that_would_end_at_the_deviation_stop():
    level = _world([])  # path along x at 2 m
    steep = parse_world({"name": "s", "path": {"waypoints": [[0, 0, 2], [6, 0, 8]]}, "obstacles": []}, "test")
    narrow = EnvConfig(
        start_jitter_m=0.0, shield=ShieldConfig(enabled=True), reward=RewardParams(max_deviation_m=0.6)
    )
    env = VecQuadNavEnv([level], 1, seed=0, config=narrow)
    env.reset()
    assert env.allowed.all()  # nothing seen, no band: every primitive flies
    banded = dataclasses.replace(narrow, shield_band=True)
    env = VecQuadNavEnv([level], 1, seed=0, config=banded)
    env.reset()
    allowed = set(np.flatnonzero(env.allowed[0]).tolist())
    assert {FORWARD, HOVER} <= allowed
    left, up_forward = DEFAULT_DIRECTIONS.index((0, 1, 0)), DEFAULT_DIRECTIONS.index((1, 0, 1))
    assert left not in allowed and up_forward not in allowed  # 1 m off a 0.6 m band
    env = VecQuadNavEnv([level, steep], 16, seed=0, config=banded)
    env.reset()
    on_steep = env.world_idx == 1
    assert on_steep.any() and (~on_steep).any()
    assert env.allowed[on_steep, up_forward].all()  # along the steep path: inside its own band
    assert not env.allowed[~on_steep, up_forward].any()
    # a filter that already keeps a band (a lab's flight config) keeps it: shield_band adds none
    steep_band = ShieldConfig(enabled=True).with_band(steep.path.waypoints_m, 0.6)
    own = dataclasses.replace(banded, shield=steep_band)
    env = VecQuadNavEnv([level], 1, seed=0, config=own)
    env.reset()
    assert env.allowed[0, up_forward] and not env.allowed[0, FORWARD]


def test_requiring_seen_space_the_allowed_set_grows_as_the_camera_sees_more():
    seen = EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True, require_seen=True))
    free = VecQuadNavEnv([_world([])], 1, seed=0, config=seen)
    free.reset()  # only what the first view covers: straight on, or stay
    assert set(np.flatnonzero(free.allowed[0]).tolist()) == {FORWARD, HOVER}
    for _ in range(2):
        free.step(np.array([FORWARD]))
    assert free.allowed[0, :9].all()  # two metres on, every forward primitive flies in seen space
    no_memory = EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True, require_seen=False))
    free = VecQuadNavEnv([_world([])], 1, seed=0, config=no_memory)
    free.reset()
    assert free.allowed.all()


def test_a_forward_only_policy_under_the_shield_does_not_crash_into_the_wall():
    def forward_if_allowed(depth, rel, allowed):
        q = np.where(np.arange(18) == FORWARD, 1.0, 0.0)[None].repeat(len(depth), 0)
        return masked_argmax(q, allowed)

    rows = evaluate(forward_if_allowed, [_world(WALL)], trials=2, seed=0, env_config=SHIELDED)
    assert not any(r.crash for r in rows)
    unshielded = EnvConfig(start_jitter_m=0.0, max_steps=30)
    assert all(r.crash for r in evaluate(forward_if_allowed, [_world(WALL)], 2, 0, unshielded))


def test_shielded_acting_keeps_to_allowed_actions_greedy_and_random():
    torch.manual_seed(0)
    agent = DQNAgent(NetworkConfig())
    rng = np.random.default_rng(0)
    allowed = np.zeros((64, 18), dtype=bool)
    allowed[:, 5] = True
    allowed[::2, 9] = True
    depth, rel = np.ones((64, 1, 32, 32), np.float32), np.zeros((64, 1, 3), np.float32)
    for eps in (0.0, 1.0):
        a = agent.act(depth, rel, eps, rng, allowed)
        assert allowed[np.arange(64), a].all()
    assert set(agent.act(depth, rel, 1.0, rng, allowed)[::2].tolist()) == {5, 9}  # random: both


def test_td_target_maxes_over_the_allowed_next_actions_only():
    torch.manual_seed(0)
    agent = DQNAgent(NetworkConfig())
    b = 8
    batch = Batch(
        depth=np.ones((b, 1, 32, 32), np.float32),
        rel=np.zeros((b, 1, 3), np.float32),
        action=np.zeros(b, np.int64),
        reward=np.zeros(b, np.float32),
        next_depth=np.random.default_rng(1).random((b, 1, 32, 32), dtype=np.float32),
        next_rel=np.zeros((b, 1, 3), np.float32),
        done=np.zeros(b, np.float32),
        n=np.ones(b, np.float32),
        index=np.arange(b),
    )
    with torch.no_grad():
        q_next = agent.target(torch.as_tensor(batch.next_depth), torch.as_tensor(batch.next_rel)).numpy()
    worst = q_next.argmin(axis=1)
    only_worst = np.zeros((b, 18), dtype=bool)
    only_worst[np.arange(b), worst] = True
    batch.next_allowed = only_worst
    np.testing.assert_allclose(agent.td_target(batch, 0.5).numpy(), 0.5 * q_next.min(axis=1), rtol=1e-5)
    batch.next_allowed = None
    np.testing.assert_allclose(agent.td_target(batch, 0.5).numpy(), 0.5 * q_next.max(axis=1), rtol=1e-5)


def test_replay_and_n_step_returns_carry_the_next_allowed_set():
    acc = NStepAccumulator(2, 2)
    buf = ReplayBuffer(16, (1, 32, 32), (1, 3), seed=0, n_actions=18)
    d, r = np.zeros((2, 1, 32, 32), np.float32), np.zeros((2, 1, 3), np.float32)
    for k in range(3):
        nxt = np.zeros((2, 18), dtype=bool)
        nxt[:, k] = True
        out = acc.push(d, r, np.zeros(2), np.ones(2), d, r, np.zeros(2, bool), np.zeros(2, bool), 0.9, nxt)
        if out:
            buf.add(**out)
    batch = buf.sample(32)
    assert batch.next_allowed is not None and batch.next_allowed.sum(axis=1).tolist() == [1] * 32
    assert set(np.flatnonzero(batch.next_allowed.any(axis=0)).tolist()) == {1, 2}


def test_a_shielded_run_records_its_shield_and_evaluation_flies_with_it(tmp_path):
    cfg = TrainConfig(
        name="sh", episodes=6, n_envs=4, max_steps=8, learning_starts=16, batch_size=8, shield=True,
        out_dir=str(tmp_path), checkpoint_every=3,
    )
    result = train(cfg, progress=False)
    policy = Policy.from_path(result.model_path)
    env_cfg = env_config_for_policy(policy, max_steps=5)
    assert env_cfg.shield.enabled and env_cfg.shield.clearance_m == cfg.shield_clearance_m
    greedy, picks = policy_greedy_fn(policy), []

    def checked(depth, rel, allowed):
        actions = greedy(depth, rel, allowed)
        picks.append(bool(allowed[np.arange(len(actions)), actions].all()) and not allowed.all())
        return actions

    rows = evaluate(checked, [_world(WALL)], 2, 0, env_cfg)
    assert len(rows) == 2 and picks and all(picks)  # the wall vetoes something; never picked


def test_ship_records_the_filter_and_eval_flies_generated_worlds_with_or_without_it(tmp_path):
    """`quadnav-sim ship` keeps the weights and records the filter; `eval --procedural` flies
    generated worlds and its JSON names the filter it flew with."""
    import json

    from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
    from quadnav_onboard.network import DQN
    from sim_harness.cli import main

    torch.manual_seed(0)
    raw = save_checkpoint(tmp_path / "raw.pt", DQN(NetworkConfig()))
    assert main(["ship", "--model", str(raw), "--out", str(tmp_path / "s.pt")]) == 0
    shipped = load_checkpoint(tmp_path / "s.pt")
    assert shipped.meta["shield"]["enabled"] is True
    original = load_checkpoint(raw).model.state_dict()
    for key, value in shipped.model.state_dict().items():
        assert torch.equal(value, original[key])
    for mode, enabled in (("model", True), ("off", False)):
        out = tmp_path / f"{mode}.json"
        args = ["eval", "--model", str(tmp_path / "s.pt"), "--procedural", "2", "--trials", "1",
                "--max-steps", "3", "--shield", mode, "--no-progress", "--json", str(out)]
        assert main(args) == 0
        data = json.loads(out.read_text())
        assert len(data["rows"]) == 2 and data["shield"]["enabled"] is enabled
        assert all(r["world"].startswith("procgen") for r in data["rows"])


def test_eval_shield_set_overrides_one_field_and_names_a_bad_key(tmp_path, capsys):
    import json

    from quadnav_onboard.checkpoint import save_checkpoint
    from quadnav_onboard.network import DQN
    from sim_harness.cli import main

    model = save_checkpoint(tmp_path / "m.pt", DQN(NetworkConfig()), meta={"shield": {"enabled": True}})
    out = tmp_path / "e.json"
    base = ["eval", "--model", str(model), "--procedural", "1", "--trials", "1", "--max-steps", "2"]
    base.append("--no-progress")
    sets = ["--shield-set", "clearance_m=0.7", "--shield-set", "memory_steps=2"]
    assert main([*base, *sets, "--json", str(out)]) == 0
    shield = json.loads(out.read_text())["shield"]
    assert shield["enabled"] and shield["clearance_m"] == 0.7 and shield["memory_steps"] == 2
    assert main([*base, "--shield-set", "clearence_m=0.7"]) == 2
    assert "clearence_m" in capsys.readouterr().err


def test_init_model_starts_from_its_weights_and_a_mismatch_fails_before_a_run_directory(tmp_path):
    from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.network import DQN

    torch.manual_seed(3)
    start = save_checkpoint(tmp_path / "start.pt", DQN(NetworkConfig()))
    cfg = TrainConfig(
        name="ft", episodes=2, n_envs=2, max_steps=3, learning_starts=10_000, init_model=str(start),
        out_dir=str(tmp_path / "runs"),
    )
    result = train(cfg, progress=False)  # no update happens: the weights must come through unchanged
    got = load_checkpoint(result.model_path).model.state_dict()
    want = load_checkpoint(start).model.state_dict()
    assert all(torch.equal(got[k], want[k]) for k in want)
    bad = TrainConfig(name="bad", episodes=2, n_envs=2, dueling=True, init_model=str(start),
                      out_dir=str(tmp_path / "bad_runs"))
    with pytest.raises(ConfigError, match="init_model"):
        train(bad, progress=False)
    assert not (tmp_path / "bad_runs").exists()


def test_init_model_sha256_pins_the_start_and_a_changed_file_fails_before_a_run_directory(tmp_path):
    """With ``init_model_sha256`` set, training starts only from a file with that hash; another
    file under the same name is refused, naming the key, both hashes, before a run directory."""
    from quadnav_onboard.checkpoint import load_checkpoint, save_checkpoint
    from quadnav_onboard.config import ConfigError
    from quadnav_onboard.network import DQN

    torch.manual_seed(3)
    start = save_checkpoint(tmp_path / "start.pt", DQN(NetworkConfig()))
    sha = load_checkpoint(start).sha256
    pinned = TrainConfig(name="pin", episodes=2, n_envs=2, max_steps=3, learning_starts=10_000,
                         init_model=str(start), init_model_sha256=sha, out_dir=str(tmp_path / "runs"))
    assert train(pinned, progress=False).model_path.exists()
    torch.manual_seed(4)
    save_checkpoint(start, DQN(NetworkConfig()))  # another model under the pinned name
    changed = dataclasses.replace(pinned, out_dir=str(tmp_path / "changed_runs"))
    with pytest.raises(ConfigError, match=rf"init_model_sha256.*{sha}.*has sha256 '(?!{sha})[0-9a-f]{{64}}'"):
        train(changed, progress=False)
    assert not (tmp_path / "changed_runs").exists()


@pytest.mark.parametrize(
    ("keys", "why"),
    [
        ({"init_model_sha256": "ab" * 32}, "set init_model"),
        ({"init_model": "m.pt", "init_model_sha256": "AB" * 32}, "64 lowercase hex digits"),
        ({"init_model": "m.pt", "init_model_sha256": "ab" * 31}, "64 lowercase hex digits"),
    ],
)
def test_a_bad_init_model_sha256_is_refused_naming_file_key_and_value(keys: dict, why: str) -> None:
    from quadnav_onboard.config import ConfigError
    from sim_harness.rl.config import load_train_config

    with pytest.raises(ConfigError, match=rf"recipe\.yaml: key 'init_model_sha256': bad value .*{why}"):
        load_train_config(keys, "recipe.yaml")


def _low_world(floor: bool) -> object:
    spec = {"name": "low", "path": {"waypoints": [[0, 0, 0.7], [12, 0, 0.7]]}}
    if floor:
        spec["bounds"] = {"floor_z": 0.0}
    return parse_world(spec, "test")


def test_the_env_gives_the_filter_each_worlds_floor() -> None:
    """0.7 m above a world's floor, the env's verdict vetoes every primitive that goes down 1 m.
    Without ``known_floor`` the camera's view of the floor ahead still vetoes the forward descents,
    but not the straight ones onto the floor below, which it cannot see (the crashes this fixes);
    a world without a floor vetoes nothing."""
    down = [a for a, d in enumerate(DEFAULT_DIRECTIONS) if d[2] < 0]
    straight_down = [a for a, d in enumerate(DEFAULT_DIRECTIONS) if d[2] < 0 and d[0] == 0]
    level = [a for a, d in enumerate(DEFAULT_DIRECTIONS) if d[2] >= 0]
    unknown = EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True, known_floor=False))
    allowed = {}
    for name, world, cfg in (
        ("known", _low_world(True), SHIELDED),
        ("no floor", _low_world(False), SHIELDED),
        ("unknown", _low_world(True), unknown),
    ):
        env = VecQuadNavEnv([world], 1, seed=0, config=cfg, autoreset=False)
        env.reset()
        assert env.allowed[0, level].all(), name
        allowed[name] = env.allowed[0].copy()
    assert not allowed["known"][down].any()
    assert allowed["no floor"][down].all()
    forward_down = sorted(set(down) - set(straight_down))
    assert allowed["unknown"][straight_down].all() and not allowed["unknown"][forward_down].any()


def test_the_env_remembers_the_nearest_surface_view() -> None:
    """A pole thinner than a cell 5 m ahead of a wall at 8 m: with ``depth_pooling: min`` the
    filter's memory holds it at ~4.95 m; with ``mean`` it holds the blend, well behind it."""
    world = _world([
        {"type": "box", "center": [8.5, 0, 2], "size": [1, 12, 8]},
        {"type": "cylinder", "center": [5, 0, 2], "radius": 0.09, "height": 8},
    ])
    nearest = {}
    for pooling in ("min", "mean"):
        cfg = EnvConfig(start_jitter_m=0.0, shield=ShieldConfig(enabled=True, depth_pooling=pooling))
        env = VecQuadNavEnv([world], 1, seed=0, config=cfg, autoreset=False)
        depth, _ = env.reset()
        assert env.memory is not None
        nearest[pooling] = float(env.memory.depth_m[0, -1].min())
        assert depth[0, -1].min() > 0.55  # the network's input blends the pole either way
    assert nearest["min"] == pytest.approx(4.95, abs=0.05)
    assert nearest["mean"] > 5.5
