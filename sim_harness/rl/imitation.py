"""Imitation of a teacher with DAgger (before, or instead of, the RL episodes).

Iteration ``i`` (0, 1, ...) of :func:`dagger`:

1. **Roll out** ``dagger_episodes`` episodes per primitive scale in ``imitation_scales``; at each
   step every running env takes the teacher's primitive with probability ``dagger_beta ** i``
   (iteration 0: the teacher alone), else the network's greedy one (Ross et al. 2011). With
   ``dagger_noise`` > 0 each env's step is, with that probability, a random primitive instead
   (uniform among those its flight allows), whoever would have flown it: the flights leave the
   paths the teacher and the network keep to, and the teacher labels the states they find there
   (DART; Laskey et al. 2017).
2. **Label** every visited state, whoever flew it, and **aggregate** it into one dataset
   (:class:`Aggregate`: every iteration's states are kept, up to ``imitation_buffer``). The
   teacher (a :class:`Labeller`) is either the privileged one
   (:class:`sim_harness.rl.teacher.Teacher`: its costs of all primitives against the true world as
   a soft target, ``imitation_temperature_m``) or the product itself
   (:class:`sim_harness.rl.filter_teacher.FilterTeacher`: a frozen network behind the depth safety
   filter; its Q-values with the vetoed primitives pushed down).
3. **Fit** the network to the aggregate (``imitation_epochs`` passes, or ``imitation_updates``
   minibatches whatever its size, of ``batch_size`` each, Adam at ``imitation_lr``, falling to
   ``imitation_lr_end`` by the last iteration when that is set): its
   Q-values as logits by cross-entropy to soft targets, or its Q-values to Q labels by the Huber
   loss (the teacher's ``loss``), optionally plus DQfD's large-margin loss towards the label's
   first choice (``imitation_margin_weight``).

The network is the one the RL loop and the daemon use, unchanged: the greedy action is the
arg-max of the same 18 outputs, and the order of the others is the teacher's, which is what the
safety filter falls back on when it vetoes the first choice.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import NamedTuple, Protocol

import numpy as np
import structlog
import torch
import torch.nn.functional as F
from numpy.typing import NDArray

from quadnav_onboard.config import PrimitiveConfig
from sim_harness.env import EnvConfig, VecQuadNavEnv
from sim_harness.rl.agent import DQNAgent, random_allowed
from sim_harness.world import World

__all__ = [
    "Aggregate", "DaggerSettings", "DaggerTask", "Labeller", "Labels", "WorldCurriculum", "collect", "dagger",
    "decisive_rows", "first_choice_agreement", "fit", "holding_primitives", "lr_at", "margin_loss",
    "veto_loss",
]

log = structlog.get_logger(__name__)


@dataclass(frozen=True)
class DaggerSettings:
    """What :func:`dagger` does (the ``TrainConfig`` fields of the same names)."""

    iterations: int
    episodes: int
    beta: float
    epochs: float
    lr: float
    temperature_m: float
    batch_size: int
    buffer: int
    seed: int
    filtered_share: float = 0.0
    updates: int = 0
    margin_weight: float = 0.0
    margin: float = 1.0
    margin_min_gap_m: float = 0.0
    """The large-margin loss only where the teacher's first choice costs at least this much less
    than its second (metres of its cost); 0: in every state."""
    margin_against_holding: bool = False
    """The large-margin loss against the primitives that do not move forward alone
    (:func:`holding_primitives`), in the states where the teacher's first choice moves forward."""
    lr_end: float | None = None
    veto_weight: float = 0.0
    noise: float = 0.0
    """Probability that an env's step is a random primitive (``dagger_noise``)."""
    curriculum_floor: float | None = None
    """:class:`WorldCurriculum`'s floor (``dagger_world_sampling`` "failures"); None: every world alike."""


class Aggregate:
    """DAgger's dataset: observations and the teacher's soft targets, kept across iterations.

    Depth is stored as float16 (inputs in [0, 1]: 1e-3 resolution). Past ``capacity`` the oldest
    rows are overwritten."""

    def __init__(self, capacity: int, depth_shape: tuple[int, ...], rel_shape: tuple[int, ...],
                 n_actions: int) -> None:
        if capacity < 1:
            raise ValueError(f"Aggregate capacity must be >= 1, got {capacity}")
        self.capacity = int(capacity)
        self.depth = np.zeros((capacity, *depth_shape), dtype=np.float16)
        self.rel = np.zeros((capacity, *rel_shape), dtype=np.float32)
        self.target = np.zeros((capacity, n_actions), dtype=np.float32)
        self.allowed = np.ones((capacity, n_actions), dtype=bool)
        """The primitives the env's depth safety filter allowed in each state (all when it is off)."""
        self.released = np.zeros(capacity, dtype=bool)
        """The states whose labels leave the filter's verdicts aside (``TeacherConfig.release_m``)."""
        self.iteration = np.zeros(capacity, dtype=np.int32)
        """The DAgger iteration each row was collected in."""
        self.scale_m = np.full(capacity, np.nan, dtype=np.float32)
        """The primitive scale (m) each row was flown at (a network that reads the scale fits it);
        NaN where the caller did not say, which such a network refuses."""
        self.size = 0
        self._next = 0
        self.added = 0
        """Rows ever added, those the ring has since overwritten included."""
        self.added_released = 0
        """Of those, the released ones."""

    def __len__(self) -> int:
        return self.size

    def add(self, depth: NDArray, rel: NDArray, target: NDArray, iteration: int,
            allowed: NDArray[np.bool_] | None = None, released: NDArray[np.bool_] | None = None,
            scale_m: float | None = None) -> None:
        n = depth.shape[0]
        if not (rel.shape[0] == n and target.shape[0] == n):
            raise ValueError("depth, rel and target need the same number of rows")
        if allowed is not None and allowed.shape != target.shape:
            raise ValueError(f"allowed {allowed.shape} and target {target.shape} differ in shape")
        idx = (self._next + np.arange(n)) % self.capacity
        self.depth[idx] = depth
        self.rel[idx] = rel
        self.target[idx] = target
        self.allowed[idx] = True if allowed is None else allowed
        self.released[idx] = False if released is None else released
        self.iteration[idx] = iteration
        self.scale_m[idx] = np.nan if scale_m is None else scale_m
        self._next = int((self._next + n) % self.capacity)
        self.size = min(self.capacity, self.size + n)
        self.added += n
        self.added_released += 0 if released is None else int(np.count_nonzero(released))


class WorldCurriculum:
    """Failure-weighted world sampling (after prioritised level replay, Jiang et al. 2021): each
    world's weight is ``floor`` plus its recent failure rate, the share of its episodes that did
    not reach the goal; :meth:`next_weights` halves the counts so far, so each iteration weighs
    half the next. A world not yet flown counts as half failed ((failures + 0.5) / (episodes + 1))."""

    def __init__(self, n_worlds: int, floor: float) -> None:
        if n_worlds < 1 or not floor > 0:
            raise ValueError(f"need n_worlds >= 1 and floor > 0, got {n_worlds}, {floor}")
        self.floor = float(floor)
        self.episodes = np.zeros(n_worlds)
        self.failures = np.zeros(n_worlds)

    def record(self, world: int, outcome: str) -> None:
        self.episodes[world] += 1
        self.failures[world] += outcome != "goal"

    def failure_rate(self) -> NDArray[np.float64]:
        return (self.failures + 0.5) / (self.episodes + 1.0)

    def next_weights(self) -> NDArray[np.float64]:
        """The weights for the next iteration's episodes; then the counts so far are halved."""
        weights = self.floor + self.failure_rate()
        self.episodes *= 0.5
        self.failures *= 0.5
        return weights


class Labels(NamedTuple):
    """A teacher's labels for N states."""

    targets: NDArray[np.float32]
    """What the student fits (N, A): a distribution, or Q-values (the teacher's ``loss``)."""
    actions: NDArray[np.int64]
    """The teacher's own primitive in each state (N,)."""
    released: NDArray[np.bool_]
    """The states (N,) whose labels leave the filter's verdicts aside: the hinge skips them."""


class Labeller(Protocol):
    """A teacher: labels for every env's current state, and the actions it would fly there."""

    loss: str
    """"cross_entropy" (labels are distributions) or "huber" (labels are Q-values)."""

    def label(self, env: VecQuadNavEnv, depth: NDArray, rel: NDArray, temperature_m: float
              ) -> Labels: ...


def collect(
    env: VecQuadNavEnv,
    teacher: Labeller,
    agent: DQNAgent,
    episodes: int,
    beta: float,
    rng: np.random.Generator,
    temperature_m: float,
    data: Aggregate,
    iteration: int,
    filtered_share: float = 0.0,
    curriculum: WorldCurriculum | None = None,
    keep_verdicts: bool = True,
    noise: float = 0.0,
) -> dict[str, int]:
    """Fly ``episodes`` episodes in ``env`` (auto-reset) with the β-mixture of teacher and network,
    adding every visited state with the teacher's label to ``data``; returns the outcome counts of
    the episodes (those the network flew when β = 0). The first ``filtered_share`` of the envs fly
    the network behind the env's filter (its ``allowed``), as the product does; the rest alone.
    ``curriculum`` records each counted episode's world and outcome. ``keep_verdicts``: the
    filter's verdicts are kept with the labels (for the hinge); without, every primitive counts
    as allowed there. ``noise``: the probability that an env's step is a random primitive instead,
    uniform among the filter's allowed ones in the envs that fly behind it and among all in the
    others; 0 draws no random number for it, so the flights are those without the key."""
    if not 0.0 <= noise <= 1.0:
        raise ValueError(f"noise must be a probability in [0, 1], got {noise!r}")
    filtered = np.arange(env.n_envs) < round(filtered_share * env.n_envs)
    scale_m = float(env.config.primitives.scale_m)
    counts: dict[str, int] = {}
    finished = 0
    depth, rel = env.depth, env.rel
    while finished < episodes:
        target, actions, released = teacher.label(env, depth, rel, temperature_m)
        # a label that leaves the filter aside carries no verdict: every primitive counts as allowed
        verdicts = np.where(released[:, None], True, env.allowed) if keep_verdicts else None
        data.add(depth, rel, target, iteration, verdicts, released, scale_m)
        # what each env's flight allows: behind the filter its verdicts, alone every primitive
        flyable = np.where(filtered[:, None], env.allowed, True)
        if beta < 1.0:
            own = rng.random(env.n_envs) >= beta
            if own.any():
                actions[own] = agent.greedy(depth[own], rel[own], flyable[own], scale_m)
        if noise > 0.0:
            jolt = rng.random(env.n_envs) < noise
            if jolt.any():
                actions[jolt] = random_allowed(flyable[jolt], rng)
        depth, rel, _, term, trunc, info = env.step(actions)
        for i in np.flatnonzero(term | trunc):
            if finished < episodes:
                key = str(info["outcome"][i])
                counts[key] = counts.get(key, 0) + 1
                finished += 1
                if curriculum is not None:
                    curriculum.record(int(info["world_index"][i]), key)
    return counts


def margin_loss(q: torch.Tensor, expert: torch.Tensor, margin: float,
                rows: torch.Tensor | None = None, against: torch.Tensor | None = None) -> torch.Tensor:
    """The large-margin classification loss of DQfD (Hester et al. 2018), batch mean:
    max_a [Q(s, a) + ``margin`` if a is not the expert's action] - Q(s, a_E). Zero where the
    expert's action ``expert`` (N,) leads every other by at least ``margin``, and in the rows
    outside ``rows`` (N,) bool, when given (the mean is still over all N). With ``against`` (A,)
    bool, the max runs over the expert's action and those primitives alone: the expert's action
    should lead them, and the others are left free."""
    penalty = torch.full_like(q, float(margin))
    if against is not None:
        penalty = penalty.masked_fill(~against.to(device=q.device, dtype=torch.bool)[None, :], float("-inf"))
    penalty.scatter_(1, expert[:, None], 0.0)
    per_row = (q + penalty).max(dim=1).values - q.gather(1, expert[:, None]).squeeze(1)
    if rows is not None:
        per_row = per_row * rows.to(per_row.dtype)
    return per_row.mean()


def decisive_rows(target: torch.Tensor, min_log_ratio: float) -> torch.Tensor:
    """The rows (N,) of soft targets (N, A) whose first choice is at least ``exp(min_log_ratio)``
    times as likely as their second: with the privileged teacher's targets, softmax(-cost / T),
    the states where its first choice costs at least ``min_log_ratio`` × T less than any other."""
    top2 = target.topk(2, dim=1).values
    tiny = torch.finfo(target.dtype).tiny
    return torch.log(top2[:, 0].clamp_min(tiny)) - torch.log(top2[:, 1].clamp_min(tiny)) >= min_log_ratio


def holding_primitives(primitives: PrimitiveConfig) -> NDArray[np.bool_]:
    """(A,) bool: the primitives that do not move forward (no forward component in the heading
    frame), the ones a vehicle holds back with."""
    return ~(np.asarray(primitives.directions, dtype=float)[:, 0] > 0)


def veto_loss(q: torch.Tensor, allowed: torch.Tensor, margin: float) -> torch.Tensor:
    """Hinge on the filter's verdicts, batch mean: max(0, max Q of a vetoed primitive + ``margin``
    - max Q of an allowed one) in each row that has both, 0 in the others: the network's first
    choice should be one the filter allows, by ``margin``, whichever of the allowed it is."""
    some = allowed.any(dim=1) & ~allowed.all(dim=1)
    if not bool(some.any()):
        return q.sum() * 0.0
    q, allowed = q[some], allowed[some]
    low = torch.finfo(q.dtype).min
    best_allowed = q.masked_fill(~allowed, low).max(dim=1).values
    best_vetoed = q.masked_fill(allowed, low).max(dim=1).values
    return F.relu(best_vetoed + float(margin) - best_allowed).sum() / some.numel()


def fit(agent: DQNAgent, data: Aggregate, epochs: float, batch_size: int, rng: np.random.Generator,
        optimizer: torch.optim.Optimizer, loss_kind: str = "cross_entropy", updates: int = 0,
        margin_weight: float = 0.0, margin: float = 1.0, veto_weight: float = 0.0,
        margin_min_log_ratio: float = 0.0, margin_against: NDArray[np.bool_] | None = None
        ) -> tuple[float, float]:
    """``epochs`` passes (fractions allowed), or ``updates`` minibatches when > 0, of cross-entropy
    between softmax(Q) and the targets (``loss_kind`` "cross_entropy"), or of the Huber loss
    between Q and the targets ("huber"), plus ``margin_weight`` times :func:`margin_loss` towards
    the targets' arg-max (when ``margin_min_log_ratio`` > 0, in the :func:`decisive_rows` alone;
    cross-entropy only; with ``margin_against`` (A,) bool, against those primitives alone and only
    in the rows whose arg-max is not one of them) and ``veto_weight`` times :func:`veto_loss` on
    the filter's verdicts kept with them; returns the mean loss and the share of the last tenth's
    samples whose arg-max Q is the teacher's first choice. The target network is set to the result."""
    if loss_kind not in ("cross_entropy", "huber"):
        raise ValueError(f"loss_kind must be 'cross_entropy' or 'huber', got {loss_kind!r}")
    if not (margin_weight >= 0 and veto_weight >= 0 and margin > 0 and margin_min_log_ratio >= 0):
        raise ValueError(f"need margin_weight >= 0, veto_weight >= 0, margin > 0 and "
                         f"margin_min_log_ratio >= 0, got {margin_weight!r}, {veto_weight!r}, "
                         f"{margin!r}, {margin_min_log_ratio!r}")
    if margin_min_log_ratio > 0 and loss_kind != "cross_entropy":
        raise ValueError("margin_min_log_ratio reads the targets as probabilities: it needs the "
                         f"cross-entropy fit, got {loss_kind!r}")
    against = None
    if margin_against is not None:
        against = agent._t(np.asarray(margin_against, dtype=bool))
        if against.shape != (data.target.shape[1],) or not bool(against.any()):
            raise ValueError(f"margin_against must be {data.target.shape[1]} bools, some true, "
                             f"got shape {tuple(against.shape)}")
    n_batches = updates if updates > 0 else max(1, round(epochs * len(data) / batch_size))
    losses: list[float] = []
    agree: list[float] = []
    agent.q.train()
    for _ in range(n_batches):
        idx = rng.integers(0, len(data), size=min(batch_size, len(data)))
        depth = agent._t(data.depth[idx].astype(np.float32))
        rel = agent._t(data.rel[idx])
        target = agent._t(data.target[idx])
        q = agent.q(depth, rel, agent.scale_rows(data.scale_m[idx], len(idx)))
        if loss_kind == "huber":
            loss = F.smooth_l1_loss(q, target)
        else:
            loss = -(target * F.log_softmax(q, dim=1)).sum(dim=1).mean()
        if margin_weight > 0:
            expert = target.argmax(dim=1)
            rows = decisive_rows(target, margin_min_log_ratio) if margin_min_log_ratio > 0 else None
            if against is not None:
                onward = ~against[expert]
                rows = onward if rows is None else rows & onward
            loss = loss + margin_weight * margin_loss(q, expert, margin, rows, against)
        if veto_weight > 0:
            allowed = torch.as_tensor(data.allowed[idx], device=q.device)
            loss = loss + veto_weight * veto_loss(q, allowed, margin)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(agent.q.parameters(), 10.0)
        optimizer.step()
        losses.append(float(loss.detach()))
        agree.append(float((q.argmax(dim=1) == target.argmax(dim=1)).float().mean()))
    agent.target.load_state_dict(agent.q.state_dict())
    last = max(1, n_batches // 10)
    return float(np.mean(losses)), float(np.mean(agree[-last:]))


def first_choice_agreement(agent: DQNAgent, data: Aggregate, rows: NDArray[np.int64], batch: int = 4096
                           ) -> float | None:
    """The share of the aggregate's ``rows`` whose arg-max Q is the teacher's first choice (the
    arg-max of its target), the network in eval mode and no gradient: a pure measurement, which
    changes no weight and draws no random number. None for no rows."""
    if rows.size == 0:
        return None
    agent.q.eval()
    hits = 0
    with torch.no_grad():
        for start in range(0, rows.size, batch):
            idx = rows[start:start + batch]
            q = agent.q(agent._t(data.depth[idx].astype(np.float32)), agent._t(data.rel[idx]),
                        agent.scale_rows(data.scale_m[idx], len(idx)))
            hits += int((q.argmax(dim=1).cpu().numpy() == data.target[idx].argmax(axis=1)).sum())
    return hits / rows.size


def lr_at(settings: DaggerSettings, iteration: int) -> float:
    """The fit's step size in ``iteration``: ``lr`` throughout, or with ``lr_end`` set, from
    ``lr`` in the first iteration to ``lr_end`` in the last, geometrically."""
    s = settings
    if s.lr_end is None or s.iterations < 2:
        return s.lr
    return float(s.lr * (s.lr_end / s.lr) ** (iteration / (s.iterations - 1)))


@dataclass(frozen=True)
class DaggerTask:
    """One set of envs DAgger flies: their config, worlds and teacher (``make_env`` builds them,
    e.g. with depth noise; default :class:`~sim_harness.env.VecQuadNavEnv`)."""

    config: EnvConfig
    worlds: Sequence[World]
    teacher: Labeller
    make_env: Callable[..., VecQuadNavEnv] = VecQuadNavEnv
    filter_verdicts: bool = True
    """Keep the filter's verdicts with this task's labels, for the hinge (``veto_weight``)."""
    noise: float | None = None
    """Probability of a random step in this task's flights; None = the settings' ``noise``."""


def dagger(agent: DQNAgent, tasks: Sequence[DaggerTask], settings: DaggerSettings, n_envs: int) -> list[dict]:
    """Run DAgger on ``agent.q`` over ``tasks`` (e.g. one per primitive scale, and a lab's
    layouts under its flight config); returns one record per iteration and task (outcomes, the
    random steps' probability it flew with, dataset size, the released states in the aggregate,
    the states this task labelled in this iteration and how many of them its teacher released,
    loss, wall time; on each iteration's last record the fit's ``agreement`` with the teacher's
    first choice on the states it fitted, and ``agreement_new`` on the states this iteration
    added, by the network before it fitted them: states it has not learned from). Every task's
    teacher must fit by the same loss."""
    s = settings
    if not tasks:
        raise ValueError("dagger needs at least one task")
    losses = {t.teacher.loss for t in tasks}
    if len(losses) != 1:
        raise ValueError(f"dagger: the tasks' teachers fit by different losses: {sorted(losses)}")
    (loss_kind,) = losses
    if s.margin_min_gap_m > 0 and loss_kind != "cross_entropy":
        raise ValueError(f"dagger: margin_min_gap_m {s.margin_min_gap_m!r} reads the teacher's soft "
                         f"targets, but its labels fit by {loss_kind!r}")
    env0 = tasks[0].config
    against = holding_primitives(env0.primitives) if s.margin_against_holding else None
    rng = np.random.default_rng(s.seed + 7)
    n_actions = env0.primitives.build().n_actions
    data = Aggregate(s.buffer, (env0.depth_history, 32, 32), (env0.position_history, 3), n_actions)
    envs = [
        t.make_env(list(t.worlds), n_envs, seed=s.seed + 101 * (k + 1), config=t.config)
        for k, t in enumerate(tasks)
    ]
    curricula = [
        None if s.curriculum_floor is None else WorldCurriculum(len(env.worlds), s.curriculum_floor)
        for env in envs
    ]
    for env in envs:
        env.reset()
    optimizer = torch.optim.Adam(agent.q.parameters(), lr=s.lr)
    records: list[dict] = []
    t0 = time.monotonic()
    for it in range(s.iterations):
        beta = s.beta**it
        for group in optimizer.param_groups:
            group["lr"] = lr_at(s, it)
        agent.q.eval()
        for env, task, curriculum in zip(envs, tasks, curricula, strict=True):
            added, added_released = data.added, data.added_released
            noise = s.noise if task.noise is None else task.noise
            counts = collect(env, task.teacher, agent, s.episodes, beta, rng, s.temperature_m, data, it,
                             s.filtered_share, curriculum, task.filter_verdicts, noise=noise)
            records.append({
                "iteration": it, "beta": round(beta, 6), "scale_m": task.config.primitives.scale_m,
                "worlds": len(task.worlds), "noise": noise,
                "outcomes": counts, "dataset": len(data),
                "released": int(data.released[:len(data)].sum()),
                "labelled": data.added - added, "labelled_released": data.added_released - added_released,
            })
            if curriculum is not None:
                weights = curriculum.next_weights()
                env.set_world_weights(weights)
                records[-1]["world_weights"] = [round(float(w), 4) for w in weights]
        new_rows = np.flatnonzero(data.iteration[:len(data)] == it)
        agreement_new = first_choice_agreement(agent, data, new_rows)
        loss, agreement = fit(agent, data, s.epochs, s.batch_size, rng, optimizer, loss_kind, s.updates,
                              s.margin_weight, s.margin, s.veto_weight,
                              margin_min_log_ratio=s.margin_min_gap_m / s.temperature_m,
                              margin_against=against)
        records[-1]["loss"] = round(loss, 6)
        records[-1]["agreement"] = round(agreement, 4)
        records[-1]["agreement_new"] = None if agreement_new is None else round(agreement_new, 4)
        records[-1]["wall_s"] = round(time.monotonic() - t0, 2)
        log.info("dagger iteration", iteration=it, beta=round(beta, 4), dataset=len(data),
                 loss=round(loss, 4), agreement=round(agreement, 3),
                 agreement_new=records[-1]["agreement_new"], released=records[-1]["released"],
                 outcomes=[r["outcomes"] for r in records[-len(envs):]], wall_s=records[-1]["wall_s"])
    return records
