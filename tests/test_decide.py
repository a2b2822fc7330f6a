"""The split decision (quadnav_onboard.daemon.decide): prepared frames give the full decision's result."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from quadnav_onboard.checkpoint import save_checkpoint
from quadnav_onboard.daemon.decide import Decider, Motion
from quadnav_onboard.network import DQN, NetworkConfig
from quadnav_onboard.observation import ObservationHistory
from quadnav_onboard.policy import Policy
from quadnav_onboard.preprocess import DepthFrameError, PreprocessConfig, preprocess_depth_mm
from quadnav_onboard.primitives import DEFAULT_DIRECTIONS, PrimitiveSet
from quadnav_onboard.shield import ShieldConfig, points_per_view
from quadnav_onboard.sources.base import DepthFrame, OdometrySample


@pytest.fixture(scope="module")
def policy(tmp_path_factory: pytest.TempPathFactory) -> Policy:
    torch.manual_seed(4)
    cfg = NetworkConfig(depth_history=3, position_history=2, dueling=True)
    return Policy.from_path(save_checkpoint(tmp_path_factory.mktemp("m") / "m.pt", DQN(cfg)))


def _frames(n: int) -> list[DepthFrame]:
    rng = np.random.default_rng(5)
    return [DepthFrame(rng.integers(300, 9000, (240, 424), dtype=np.uint16), float(i), i) for i in range(n)]


def _full_decision(
    policy: Policy, history: ObservationHistory, frame: DepthFrame, rel: np.ndarray
) -> tuple[int, np.ndarray]:
    """The decision as the daemon made it before the split: preprocess, push, whole network."""
    history.push(preprocess_depth_mm(frame.depth_mm), rel)
    return policy.act(*history.arrays())


def test_prepared_decisions_equal_whole_network_ones_over_a_flight(policy: Policy) -> None:
    """Preparing each frame against a snapshot, then deciding on it, gives the same actions,
    Q-values and history as running the whole network step after step."""
    decider = Decider(policy, PreprocessConfig())
    reference = ObservationHistory(policy.depth_history, policy.position_history)
    rng = np.random.default_rng(6)
    for frame in _frames(6):
        rel = rng.normal(size=3)
        prepared = decider.prepare(frame, decider.snapshot())
        assert decider.current(frame) is prepared
        decision = decider.decide(prepared, rel, "prepared")
        action, q = _full_decision(policy, reference, frame, rel)
        assert decision.action == action
        np.testing.assert_array_equal(decision.q, q)
        np.testing.assert_array_equal(decider.history.arrays()[0], reference.arrays()[0])
        np.testing.assert_array_equal(decision.depth_input, reference.arrays()[0][-1])


def test_a_frame_prepared_before_the_history_changed_or_another_frame_is_not_current(policy: Policy) -> None:
    decider = Decider(policy, PreprocessConfig())
    f0, f1, f2 = _frames(3)
    stale = decider.prepare(f1, decider.snapshot())
    decider.decide(decider.prepare(f0, decider.snapshot()), np.zeros(3), "full")
    assert decider.current(f1) is None and decider.current(f0) is None
    with pytest.raises(RuntimeError, match="older history"):
        decider.decide(stale, np.zeros(3), "prepared")
    decider.prepare(f2, decider.snapshot())
    assert decider.current(f1) is None and decider.current(f2) is not None


def test_a_preparation_never_touches_the_live_history(policy: Policy) -> None:
    """The executor side works on its snapshot; only decide() (on the loop) pushes."""
    decider = Decider(policy, PreprocessConfig())
    for frame in _frames(3):
        decider.prepare(frame, decider.snapshot())
    assert not decider.history.ready and decider.history.version == 0


def test_an_unusable_frame_raises_depth_frame_error(policy: Policy) -> None:
    decider = Decider(policy, PreprocessConfig())
    blank = DepthFrame(np.zeros((240, 424), np.uint16), 0.0, 1)
    with pytest.raises(DepthFrameError):
        decider.prepare(blank, decider.snapshot())
    assert decider.prepared is None


def _wall_frame(distance_mm: int) -> DepthFrame:
    return DepthFrame(np.full((240, 424), distance_mm, dtype=np.uint16), 0.0, 0)


def _still(pos: tuple[float, float, float] = (0.0, 0.0, 2.0)) -> Motion:
    p = np.array(pos)
    return Motion(p, np.zeros(3), p.copy(), np.zeros(3), 0.0)


def test_with_the_shield_on_the_decision_keeps_out_of_a_wall_in_front(policy: Policy) -> None:
    """A wall 1.2 m ahead: no forward primitive is allowed, the chosen one is among the allowed,
    and the decision carries the verdict; with the shield off the same Q-values stand alone."""
    shielded = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=True))
    frame = _wall_frame(1200)
    decision = shielded.decide(shielded.prepare(frame, shielded.snapshot()), np.zeros(3), "full", _still())
    assert decision.allowed is not None and decision.clearance_m is not None
    forward = [i for i, d in enumerate(DEFAULT_DIRECTIONS) if d[0] == 1]
    assert not decision.allowed[forward].any()
    assert decision.allowed[decision.action]
    plain = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=False))
    unshielded = plain.decide(plain.prepare(frame, plain.snapshot()), np.zeros(3), "full")
    assert unshielded.allowed is None
    np.testing.assert_array_equal(unshielded.q, decision.q)


def test_flown_with_shorter_primitives_the_shield_remembers_more_decisions(policy: Policy) -> None:
    """The real-flight 0.5 m primitives on a model trained with 1 m ones: the filter's memory keeps
    the same distance of travel (twice the decisions), whether the shield is the model's or the
    flight config's."""
    assert policy.primitive_config().scale_m == 1.0
    half = PrimitiveSet(scale_m=0.5)
    assert Decider(policy, PreprocessConfig(), half, ShieldConfig(enabled=True)).shield.memory_steps == 8
    decider = Decider(policy, PreprocessConfig(), half, ShieldConfig(enabled=True, memory_steps=3))
    assert decider.shield.memory_steps == 6 and decider.memory is not None
    assert decider.memory.points.shape[1] == 6 * points_per_view(decider.shield)
    same = Decider(policy, PreprocessConfig(), PrimitiveSet(), ShieldConfig(enabled=True))
    assert same.shield.memory_steps == 4


def test_the_shield_sees_a_thin_pole_that_the_network_input_blurs(policy: Policy) -> None:
    """A pole 3 pixels wide, 1.0 m ahead, against a far wall: area-averaged, its cell reads ~3.4 m,
    so the network's input hides it; the shield's nearest-surface view keeps 1.0 m and vetoes
    flying straight at it ("mean" pooling, on the same frame, does not)."""
    mm = np.full((240, 424), 6000, dtype=np.uint16)
    mm[:, 211:214] = 1000
    frame = DepthFrame(mm, 0.0, 0)
    fwd = DEFAULT_DIRECTIONS.index((1, 0, 0))
    verdicts = {}
    for pooling in ("min", "mean"):
        d = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=True, depth_pooling=pooling))
        prepared = d.prepare(frame, d.snapshot())
        assert (prepared.nearest_view is None) == (pooling == "mean")
        verdicts[pooling] = d.decide(prepared, np.zeros(3), "full", _still())
    decider = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=True))
    near = decider.prepare(frame, decider.snapshot())
    assert near.nearest_view is not None and near.shield_view[0] is near.nearest_view
    assert near.nearest_at is not None and near.shield_view[1] is near.nearest_at
    assert near.nearest_view.min() == pytest.approx(0.1, abs=1e-6)
    assert near.depth_input.min() > 0.25  # blurred into the background
    assert not verdicts["min"].allowed[fwd] and verdicts["mean"].allowed[fwd]
    assert verdicts["min"].clearance_m[fwd] < 0.5 < verdicts["mean"].clearance_m[fwd]


def test_the_daemons_filter_knows_the_floor_at_world_z_zero(policy: Policy) -> None:
    """0.7 m up, a far wall ahead: the step straight down (below the camera's view) is vetoed
    because the floor is known (``decide.FLOOR_Z_M``), and allowed with ``known_floor: false``."""
    down = DEFAULT_DIRECTIONS.index((0, 0, -1))
    verdict = {}
    for known in (True, False):
        d = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=True, known_floor=known))
        prepared = d.prepare(_wall_frame(9000), d.snapshot())
        verdict[known] = d.decide(prepared, np.zeros(3), "full", _still((0.0, 0.0, 0.7)))
    assert not verdict[True].allowed[down] and verdict[True].clearance_m[down] == 0.0
    assert verdict[False].allowed[down]


def test_the_shield_needs_the_vehicles_motion(policy: Policy) -> None:
    decider = Decider(policy, PreprocessConfig(), shield=ShieldConfig(enabled=True))
    prepared = decider.prepare(_wall_frame(5000), decider.snapshot())
    with pytest.raises(ValueError, match="motion"):
        decider.decide(prepared, np.zeros(3), "full")


def test_the_decider_flies_the_shield_the_checkpoint_names(tmp_path) -> None:
    meta = {"shield": {"enabled": True, "clearance_m": 0.7}}
    path = save_checkpoint(tmp_path / "s.pt", DQN(NetworkConfig()), meta=meta)
    decider = Decider(Policy.from_path(path), PreprocessConfig())
    assert decider.shield.enabled and decider.shield.clearance_m == 0.7
    assert not Decider(Policy.from_path(path), PreprocessConfig(), shield=ShieldConfig()).shield.enabled


def test_a_shield_verdict_prepared_with_the_frame_equals_the_one_at_the_step_boundary(policy: Policy) -> None:
    """Preparing the verdict off the loop (motion at preparation) gives the boundary's verdict for
    the same motion, over several steps, and commits the same memory."""
    cfg = ShieldConfig(enabled=True)
    ahead = Decider(policy, PreprocessConfig(), shield=cfg)
    at_step = Decider(policy, PreprocessConfig(), shield=cfg)
    for k, dist in enumerate((4000, 2500, 1400)):
        frame = _wall_frame(dist)
        m = _still((float(k), 0.0, 2.0))
        early = ahead.decide(ahead.prepare(frame, ahead.snapshot(), m, ahead.memory), np.zeros(3), "prepared")
        late = at_step.decide(at_step.prepare(frame, at_step.snapshot()), np.zeros(3), "full", m)
        assert early.action == late.action
        np.testing.assert_array_equal(early.allowed, late.allowed)
        np.testing.assert_allclose(early.clearance_m, late.clearance_m)
        np.testing.assert_array_equal(ahead.memory.points, at_step.memory.points)


def test_motion_takes_the_odometrys_velocity_or_else_the_commanded_one() -> None:
    start, start_vel = np.array([1.0, 0.0, 2.0]), np.array([1.0, 0.5, 0.0])
    level = np.array([1.0, 0, 0, 0])
    with_vel = OdometrySample(np.array([0.9, 0.1, 2.0]), level, 0.0, np.array([0.8, 0.2, 0.0]))
    m = Motion.of(with_vel, start, start_vel, 0.3)
    np.testing.assert_array_equal(m.vel_world_m_s, [0.8, 0.2, 0.0])
    np.testing.assert_array_equal(m.pos_world_m, [0.9, 0.1, 2.0])
    no_vel = OdometrySample(np.array([0.9, 0.1, 2.0]), level, 0.0)
    np.testing.assert_array_equal(Motion.of(no_vel, start, start_vel, 0.3).vel_world_m_s, start_vel)
