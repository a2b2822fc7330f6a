"""The DQN training loop (pure orchestration: env, agent, replay, schedules, run directory).

``train(config)`` runs the paper's recipe: vectorised envs over the training worlds, ε-greedy
acting with an ε fixed per episode from the episode schedule, γ from the episode schedule at each
update, Huber loss + Adam, a target network, uniform replay. Episodes are the unit: it stops when
``config.episodes`` episodes have finished. ``train(resume=RUN_DIR)`` continues a killed run from its
last checkpoint (networks, optimiser, counters, RNG states, metrics); the replay buffer is not saved,
so it refills to ``learning_starts`` before updates resume.

Beyond the metrics files, a run writes TensorBoard event files (``tensorboard``; sim_harness.rl.tblog)
and, every ``eval_every`` episodes, a greedy evaluation of the current network on the training
worlds (``evals.json``/``evals.csv``). ``hooks`` (:class:`TrainHook`) see every finished episode and
every evaluation: a sweep's trial reports to its scheduler from there.
"""

from __future__ import annotations

import dataclasses
import json
import shutil
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol

import numba
import numpy as np
import structlog
import torch
from tqdm import tqdm

from quadnav_onboard.checkpoint import Checkpoint, load_checkpoint, save_checkpoint
from quadnav_onboard.config import ConfigError
from quadnav_onboard.network import NetworkConfig
from quadnav_onboard.reward import RewardParams
from quadnav_onboard.shield import ShieldConfig
from sim_harness.env import REFERENCE_SCALE_M, EnvConfig, VecQuadNavEnv, at_primitive_scale
from sim_harness.procgen import procedural_worlds
from sim_harness.rl.agent import AgentConfig, DQNAgent
from sim_harness.rl.config import TrainConfig, load_train_config, read_config_file
from sim_harness.rl.evaluate import evaluate, scores
from sim_harness.rl.filter_teacher import FilterTeacher
from sim_harness.rl.imitation import DaggerSettings, DaggerTask, Labeller, dagger
from sim_harness.rl.lab_task import LabSetup, lab_setup, lab_task
from sim_harness.rl.replay import NStepAccumulator, PrioritizedReplayBuffer, ReplayBuffer
from sim_harness.rl.runlog import (
    git_commit,
    make_run_dir,
    platform_info,
    plot_reward_curve,
    read_evals,
    read_metrics,
    write_evals,
    write_metrics,
)
from sim_harness.rl.schedules import LinearSchedule, linear_tail
from sim_harness.rl.tblog import TensorBoardLog, open_tensorboard
from sim_harness.rl.teacher import Teacher, teacher_config
from sim_harness.rl.widen import can_widen, widen
from sim_harness.world import World, load_world, paper_world_path

__all__ = [
    "EVAL_SEED",
    "TrainHook",
    "TrainResult",
    "TrainingInterrupted",
    "env_config_for",
    "imitate",
    "learning_rate_at",
    "network_config_for",
    "train",
]

log = structlog.get_logger(__name__)


@dataclasses.dataclass
class TrainResult:
    """What a finished run produced, and how fast."""

    run_dir: Path
    model_path: Path
    episodes: int
    env_steps: int
    updates: int
    wall_s: float

    @property
    def env_steps_per_s(self) -> float:
        return self.env_steps / max(self.wall_s, 1e-9)

    @property
    def updates_per_s(self) -> float:
        return self.updates / max(self.wall_s, 1e-9)


class TrainHook(Protocol):
    """Told of a run's progress by :func:`train` (in its thread, between steps)."""

    def on_episode(self, row: dict[str, Any]) -> None:
        """A finished episode: one row of metrics.csv."""

    def on_evaluation(self, episode: int, scores: dict[str, float], model_path: Path, run_dir: Path) -> None:
        """An evaluation (``eval_every``) of the model at ``model_path`` after ``episode`` episodes;
        the run is checkpointed at that point, so ``train(resume=run_dir)`` continues from it."""


EVAL_SEED = 1000
"""Seed of the evaluations during training (the same starts every time, so scores compare)."""


class TrainingInterrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) while training: the run was checkpointed first, so ``train(resume=run_dir)``
    (``quadnav-sim train --resume RUN_DIR``) continues it. ``result``: the run directory, the
    checkpoint just written and the episodes finished."""

    def __init__(self, result: TrainResult) -> None:
        super().__init__(f"training interrupted after {result.episodes} episodes")
        self.result = result


def env_config_for(cfg: TrainConfig) -> EnvConfig:
    return EnvConfig(
        max_steps=cfg.max_steps,
        start_jitter_m=cfg.start_jitter_m,
        random_start_prob=cfg.random_start_prob,
        depth_history=cfg.depth_history,
        position_history=cfg.position_history,
        reward=RewardParams(d_floor_m=cfg.reward_d_floor_m),
        shield=ShieldConfig(
            enabled=cfg.shield,
            clearance_m=cfg.shield_clearance_m,
            memory_steps=cfg.shield_memory_steps,
            require_seen=cfg.shield_require_seen,
            lookahead=cfg.shield_lookahead,
        ),
        shield_band=cfg.shield_band,
    )


def network_config_for(cfg: TrainConfig) -> NetworkConfig:
    return NetworkConfig(
        n_actions=18,
        depth_history=cfg.depth_history,
        position_history=cfg.position_history,
        dueling=cfg.dueling,
        width=cfg.network_width,
        scale_input=cfg.network_scale_input,
        scale_range_m=((min(cfg.imitation_scales), max(cfg.imitation_scales))
                       if cfg.network_scale_encoding == "log-range" else None),
    )


def _save_model(path: Path, agent: DQNAgent, cfg: TrainConfig, env_cfg: EnvConfig, extra: dict) -> Path:
    meta = {
        "train_config": cfg.to_dict(),
        "seed": cfg.seed,
        "git_commit": git_commit(),
        "platform": platform_info(),
        "shield": dataclasses.asdict(env_cfg.shield),
        **extra,
    }
    return save_checkpoint(
        path,
        agent.cpu_model(),
        primitives=json.loads(json.dumps(dataclasses.asdict(env_cfg.primitives))),
        preprocess=dataclasses.asdict(env_cfg.preprocess),
        meta=meta,
    )


def _init_checkpoint(cfg: TrainConfig) -> Checkpoint | None:
    """The checkpoint ``init_model`` names (None when empty); its network must be this config's."""
    if not cfg.init_model:
        return None
    init = load_checkpoint(cfg.init_model)
    if cfg.init_model_sha256 and init.sha256 != cfg.init_model_sha256:
        raise ConfigError(
            f"key 'init_model_sha256': bad value {cfg.init_model_sha256!r}: init_model "
            f"{cfg.init_model!r} has sha256 {init.sha256!r}; the file is not the one the recipe "
            "starts from"
        )
    if not can_widen(init.network, network_config_for(cfg)):
        raise ConfigError(
            f"key 'init_model': bad value {cfg.init_model!r}: its network {init.network} is not "
            f"this config's {network_config_for(cfg)} (only the histories may be longer "
            "here, the hidden layers wider, and the scale lane added)"
        )
    return init


def _init_weights(init: Checkpoint, cfg: TrainConfig) -> dict[str, torch.Tensor]:
    """``init``'s weights for this config's network: as they are, or with the longer histories'
    older inputs at zero weight and the wider layers' new units unread
    (:func:`~sim_harness.rl.widen.widen`, seeded by the config's seed)."""
    target = network_config_for(cfg)
    if init.network != target:
        log.info("init_model widened", depth_history=[init.network.depth_history, target.depth_history],
                 position_history=[init.network.position_history, target.position_history],
                 width=[init.network.width, target.width],
                 scale_input=[init.network.scale_input, target.scale_input])
    return widen(init.model, target, seed=cfg.seed)


def _rng_states(**rngs: np.random.Generator) -> dict[str, Any]:
    return {k: v.bit_generator.state for k, v in rngs.items()}


def learning_rate_at(episode: int, cfg: TrainConfig) -> float:
    """The step size at ``episode``: ``learning_rate`` through the ε/γ ramp, then linear to
    ``lr_end`` at the last episode (constant when ``lr_end`` is None)."""
    if cfg.lr_end is None:
        return cfg.learning_rate
    return linear_tail(cfg.learning_rate, cfg.lr_end, episode, cfg.episodes, cfg.schedule_fraction)


def _evaluator(
    agent: DQNAgent, worlds: Sequence[World], env_cfg: EnvConfig, cfg: TrainConfig
) -> dict[str, float]:
    """Greedy scores of the current network on ``worlds`` (its own envs and seed: training's RNGs
    are untouched); the reward with the default floor, as evaluation always reports it."""
    eval_cfg = dataclasses.replace(env_cfg, random_start_prob=0.0, reward=RewardParams())
    shield = cfg.shield
    rows = evaluate(
        lambda d, r, allowed: agent.greedy(d, r, allowed if shield else None, eval_cfg.primitives.scale_m),
        worlds,
        cfg.eval_trials,
        seed=EVAL_SEED,
        env_config=eval_cfg,
    )
    return scores(rows)


def dagger_tasks(cfg: TrainConfig, env_cfg: EnvConfig, worlds: Sequence[World],
                 filter_teacher: FilterTeacher | None = None) -> list[DaggerTask]:
    """DAgger's task at each of ``imitation_scales``: ``worlds`` rescaled, and the teacher
    (``filter_teacher`` when given, else the privileged one). At a scale outside
    ``imitation_filter_scales`` (when that is set) the privileged teacher ignores the filter and
    the task keeps no verdicts for the hinge."""
    tasks = []
    for s in cfg.imitation_scales:
        scaled_cfg, scaled = (
            at_primitive_scale(env_cfg, worlds, s) if s != REFERENCE_SCALE_M else (env_cfg, list(worlds))
        )
        teacher: Labeller = filter_teacher if filter_teacher is not None else privileged_teacher(cfg, s)
        tasks.append(DaggerTask(scaled_cfg, scaled, teacher, filter_verdicts=filter_lessons(cfg, s)))
    return tasks


def filter_lessons(cfg: TrainConfig, scale_m: float) -> bool:
    """Whether DAgger's task at ``scale_m`` learns from the filter's verdicts: at every scale, or
    only at ``imitation_filter_scales`` when that is set."""
    return not cfg.imitation_filter_scales or scale_m in cfg.imitation_filter_scales


def privileged_teacher(cfg: TrainConfig, scale_m: float) -> Teacher:
    """The privileged teacher that labels DAgger's paper-world task at ``scale_m``: it keeps to
    the filter's verdicts (``teacher_respect_filter``) where that task learns from them."""
    respect = cfg.teacher_respect_filter and filter_lessons(cfg, scale_m)
    return Teacher(teacher_config(cfg, respect_filter=respect))


def imitate(agent: DQNAgent, cfg: TrainConfig, env_cfg: EnvConfig, worlds: Sequence[World],
            run_dir: Path, lab: LabSetup | None = None) -> list[dict[str, Any]]:
    """DAgger from the ``imitation_teacher`` (``dagger_*``, ``imitation_*``, ``teacher_*``,
    ``filter_*`` fields) on ``agent``, which holds ``init_model``'s weights when one is given (the
    filter teacher's expert), over ``worlds`` at each of ``imitation_scales`` and, with ``lab``,
    ``lab_layouts`` layouts of that lab's room under its flight config; writes ``dagger.json`` and
    ``checkpoints/imitation.pt`` in ``run_dir``."""
    filter_teacher = (
        FilterTeacher(agent.q, cfg.filter_veto_margin, device=cfg.device)
        if cfg.imitation_teacher == "filter" else None
    )
    tasks = dagger_tasks(cfg, env_cfg, worlds, filter_teacher)
    if lab is not None:
        tasks.append(lab_task(cfg, lab, filter_teacher))
    settings = DaggerSettings(
        iterations=cfg.dagger_iterations, episodes=cfg.dagger_episodes, beta=cfg.dagger_beta,
        epochs=cfg.imitation_epochs, lr=cfg.imitation_lr, temperature_m=cfg.imitation_temperature_m,
        batch_size=cfg.batch_size, buffer=cfg.imitation_buffer, seed=cfg.seed,
        filtered_share=cfg.dagger_filtered_share, updates=cfg.imitation_updates,
        margin_weight=cfg.imitation_margin_weight, margin=cfg.imitation_margin,
        margin_min_gap_m=cfg.imitation_margin_min_gap_m,
        margin_against_holding=cfg.imitation_margin_against == "holding",
        lr_end=cfg.imitation_lr_end, veto_weight=cfg.imitation_veto_weight, noise=cfg.dagger_noise,
        curriculum_floor=cfg.dagger_world_floor if cfg.dagger_world_sampling == "failures" else None,
    )
    records = dagger(agent, tasks, settings, cfg.n_envs)
    (run_dir / "dagger.json").write_text(json.dumps(records, indent=1), encoding="utf-8")
    extra = {"episodes": 0, "env_steps": 0, "env": _env_meta(env_cfg)}
    _save_model(run_dir / "checkpoints" / "imitation.pt", agent, cfg, env_cfg, extra)
    return records


def train(
    config: TrainConfig | None = None,
    *,
    resume: str | Path | None = None,
    progress: bool = True,
    kill_after_episodes: int | None = None,
    hooks: Sequence[TrainHook] = (),
    evaluate_at_end: bool = True,
) -> TrainResult:
    """Train (or resume) one run; returns its directory, final model and throughput figures.

    ``kill_after_episodes`` (tests) stops abruptly after that many finished episodes, without the
    final checkpoint, as a killed process would. A KeyboardInterrupt (Ctrl-C) during the episodes
    writes a checkpoint of the episodes finished so far and raises :class:`TrainingInterrupted`.
    ``evaluate_at_end=False`` leaves out the evaluation after the last episode (a caller that
    evaluates the final model itself, as a sweep trial does).
    """
    if resume is not None:
        run_dir = Path(resume)
        cfg = load_train_config(read_config_file(run_dir / "config.json"), str(run_dir / "config.json"))
    else:
        cfg = config or TrainConfig()
    if cfg.sim_threads > 0:  # numba first: starting its OpenMP pool resets OpenMP's (torch's) count
        numba.set_num_threads(min(cfg.sim_threads, numba.config.NUMBA_NUM_THREADS))
    torch.set_num_threads(cfg.torch_threads)
    torch.manual_seed(cfg.seed)
    env_cfg = env_config_for(cfg)
    world_paths = [Path(p) for p in cfg.world_files] or [paper_world_path(i) for i in cfg.train_worlds]
    worlds = [load_world(p) for p in world_paths]  # bad worlds fail before a run directory exists
    n_listed = len(worlds)  # evaluations fly these, not the procedural ones
    worlds += procedural_worlds(cfg.procedural_worlds, cfg.procedural_seed, cfg.procedural_families)
    worlds_ref = list(worlds)  # as written for the reference scale (the imitation rescales them)
    if cfg.primitive_scale_m != REFERENCE_SCALE_M:
        env_cfg, worlds = at_primitive_scale(env_cfg, worlds, cfg.primitive_scale_m)
    init = _init_checkpoint(cfg) if resume is None else None  # fails before a run directory exists
    lab = lab_setup(cfg, env_config_for(cfg)) if cfg.lab_layouts > 0 and resume is None else None
    if resume is None:
        run_dir = make_run_dir(cfg.out_dir, cfg.name, cfg.seed)
        (run_dir / "config.json").write_text(json.dumps(cfg.to_dict(), indent=2), encoding="utf-8")
    env = VecQuadNavEnv(worlds, cfg.n_envs, seed=cfg.seed, config=env_cfg)
    agent = DQNAgent(
        network_config_for(cfg),
        AgentConfig(cfg.learning_rate, cfg.double_dqn, cfg.target_update_interval, cfg.max_grad_norm),
        device=cfg.device,
    )
    if init is not None:
        weights = _init_weights(init, cfg)
        agent.q.load_state_dict(weights)
        agent.target.load_state_dict(weights)
    if cfg.dagger_iterations > 0 and resume is None:
        imitate(agent, cfg, env_config_for(cfg), worlds_ref, run_dir, lab)
        if cfg.imitation_only:
            extra = {"episodes": 0, "env_steps": 0, "env": _env_meta(env_cfg)}
            final = _save_model(run_dir / "checkpoints" / "final.pt", agent, cfg, env_cfg, extra)
            write_metrics(run_dir, [])
            return TrainResult(run_dir, final, 0, 0, agent.n_updates, 0.0)
    kd, kp = cfg.depth_history, cfg.position_history
    n_actions = env.prims.n_actions
    shapes = (cfg.buffer_size, (kd, 32, 32), (kp, 3))
    buffer = (
        PrioritizedReplayBuffer(*shapes, seed=cfg.seed + 1, n_actions=n_actions, alpha=cfg.per_alpha)
        if cfg.prioritized_replay
        else ReplayBuffer(*shapes, seed=cfg.seed + 1, n_actions=n_actions)
    )
    act_rng = np.random.default_rng(cfg.seed + 2)
    nstep = NStepAccumulator(cfg.n_envs, cfg.n_step)
    eps_of = LinearSchedule(cfg.eps_start, cfg.eps_end, cfg.episodes, cfg.schedule_fraction)
    gamma_of = LinearSchedule(cfg.gamma_start, cfg.gamma_end, cfg.episodes, cfg.schedule_fraction)
    beta_of = LinearSchedule(cfg.per_beta_start, 1.0, cfg.episodes, 1.0)  # prioritised replay's β

    rows: list[dict[str, Any]] = []
    env_steps, wall_before = 0, 0.0
    if resume is not None and (run_dir / "state.json").is_file():
        state = json.loads((run_dir / "state.json").read_text(encoding="utf-8"))
        tstate = torch.load(run_dir / "state.pt", map_location="cpu", weights_only=True)
        agent.load_state_dict(tstate["agent"])
        torch.set_rng_state(tstate["torch_rng"])
        env.rng.bit_generator.state = state["rng"]["env"]
        buffer.rng.bit_generator.state = state["rng"]["buffer"]
        act_rng.bit_generator.state = state["rng"]["act"]
        env_steps, wall_before = int(state["env_steps"]), float(state["wall_s"])
        rows = read_metrics(run_dir)[: int(state["episodes"])]
    evals = [e for e in read_evals(run_dir) if e["episode"] <= len(rows)] if resume is not None else []
    tb: TensorBoardLog | None = open_tensorboard(run_dir) if cfg.tensorboard else None
    finished = len(rows)
    started = finished + cfg.n_envs
    env_episode = finished + np.arange(cfg.n_envs)
    depth, rel = env.reset()
    losses: list[float] = []
    update_credit = 0.0
    t0 = time.monotonic() - wall_before
    bar = tqdm(total=cfg.episodes, initial=finished, desc=cfg.name, disable=not progress, unit="ep")

    def checkpoint(final: bool = False) -> Path:
        extra = {"episodes": finished, "env_steps": env_steps, "env": _env_meta(env_cfg)}
        model = _save_model(run_dir / "checkpoints" / "latest.pt", agent, cfg, env_cfg, extra)
        torch.save(
            {"agent": agent.state_dict(), "torch_rng": torch.get_rng_state()}, run_dir / "state.pt.tmp"
        )
        (run_dir / "state.pt.tmp").replace(run_dir / "state.pt")
        state = {
            "episodes": finished,
            "env_steps": env_steps,
            "wall_s": time.monotonic() - t0,
            "rng": _rng_states(env=env.rng, buffer=buffer.rng, act=act_rng),
        }
        (run_dir / "state.json.tmp").write_text(json.dumps(state), encoding="utf-8")
        (run_dir / "state.json.tmp").replace(run_dir / "state.json")
        write_metrics(run_dir, rows)
        if cfg.keep_every and finished % cfg.keep_every == 0:
            shutil.copyfile(model, run_dir / "checkpoints" / f"ep{finished:06d}.pt")
        if final:
            model = _save_model(run_dir / "checkpoints" / "final.pt", agent, cfg, env_cfg, extra)
            plot_reward_curve(rows, run_dir / "reward_curve.png", f"{run_dir.name}")
        return model

    def evaluation(model: Path) -> None:
        agent.q.eval()
        score = _evaluator(agent, worlds[:n_listed], env_cfg, cfg)
        agent.q.train()
        evals.append({"episode": finished, "env_steps": env_steps, **score})
        write_evals(run_dir, evals)
        if tb is not None:
            tb.evaluation(finished, score)
        for hook in hooks:
            hook.on_evaluation(finished, score, model, run_dir)

    try:
        while finished < cfg.episodes:
            if cfg.lr_end is not None:
                lr = learning_rate_at(finished, cfg)
                for group in agent.optimizer.param_groups:
                    group["lr"] = lr
            gamma = gamma_of(finished)
            eps = np.array([eps_of(e) for e in env_episode])
            actions = agent.act(depth, rel, eps, act_rng, env.allowed if cfg.shield else None)
            prev_depth, prev_rel = depth.copy(), rel.copy()
            depth, rel, rew, term, trunc, info = env.step(actions)
            ended = term | trunc
            next_depth = np.where(ended[:, None, None, None], info["final_depth"], depth)
            next_rel = np.where(ended[:, None, None], info["final_rel_pos"], rel)
            next_allowed = (
                np.where(ended[:, None], info["final_allowed"], env.allowed) if cfg.shield else None
            )
            trans = nstep.push(
                prev_depth, prev_rel, actions, rew, next_depth, next_rel, term, trunc, gamma, next_allowed
            )
            if trans:
                buffer.add(**trans)
            env_steps += cfg.n_envs
            if len(buffer) >= cfg.learning_starts:
                update_credit += cfg.updates_per_step
                if isinstance(buffer, PrioritizedReplayBuffer):
                    buffer.beta = beta_of(finished)
                while update_credit >= 1.0:
                    batch = buffer.sample(cfg.batch_size)
                    losses.append(agent.update(batch, gamma))
                    buffer.update_priorities(batch.index, agent.last_td_abs)
                    update_credit -= 1.0
            for i in np.flatnonzero(ended):
                if finished >= cfg.episodes:
                    break
                rows.append(
                    {
                        "episode": finished,
                        "world": worlds[int(info["world_index"][i])].name,
                        "reward": round(float(info["episode_return"][i]), 6),
                        "length": int(info["steps"][i]),
                        "outcome": str(info["outcome"][i]),
                        "progress_m": round(float(info["progress_m"][i]), 3),
                        "epsilon": round(float(eps[i]), 6),
                        "gamma": round(gamma, 6),
                        "loss": round(float(np.mean(losses)), 6) if losses else float("nan"),
                        "env_steps": env_steps,
                        "wall_s": round(time.monotonic() - t0, 3),
                    }
                )
                losses.clear()
                finished += 1
                env_episode[i] = started
                started += 1
                bar.update(1)
                bar.set_postfix(reward=f"{rows[-1]['reward']:.2f}", eps=f"{eps[i]:.2f}", refresh=False)
                if tb is not None:
                    tb.episode(rows[-1])
                for hook in hooks:
                    hook.on_episode(rows[-1])
                keep_due = cfg.keep_every and finished % cfg.keep_every == 0
                eval_due = cfg.eval_every and finished % cfg.eval_every == 0
                due = finished % cfg.checkpoint_every == 0 or keep_due or eval_due
                if due and finished < cfg.episodes:
                    model = checkpoint()
                    if eval_due:
                        evaluation(model)
                if kill_after_episodes is not None and finished >= kill_after_episodes:
                    bar.close()
                    if tb is not None:
                        tb.close()
                    return TrainResult(
                        run_dir, run_dir / "checkpoints" / "latest.pt", finished, env_steps, 0, 0.0
                    )
    except KeyboardInterrupt:  # Ctrl-C: keep what was learned, say how to go on
        bar.close()
        model = checkpoint()
        if tb is not None:
            tb.close()
        result = TrainResult(run_dir, model, finished, env_steps, agent.n_updates, time.monotonic() - t0)
        raise TrainingInterrupted(result) from None
    bar.close()
    final = checkpoint(final=True)
    wall = time.monotonic() - t0  # training only: the closing evaluation is not in the throughput
    if cfg.eval_every and evaluate_at_end:
        evaluation(final)
    if tb is not None:
        tb.close()
    return TrainResult(
        run_dir, run_dir / "checkpoints" / "final.pt", finished, env_steps, agent.n_updates, wall
    )


def _env_meta(env_cfg: EnvConfig) -> dict[str, Any]:
    return json.loads(json.dumps(dataclasses.asdict(env_cfg)))
