"""The training configuration (one frozen, typed dataclass; a docstring per field) and its CLI flags.

CleanRL style: every field becomes a ``--flag`` whose help text is the field's docstring, so the
config, the command line and the run directory's ``config.json`` say the same thing.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import typing
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import pydantic

from quadnav_onboard.config import CONFIG_DICT, ConfigError, parse_config
from quadnav_onboard.config_reference import field_docstrings
from quadnav_onboard.shield import LOOKAHEADS
from sim_harness.procgen import FAMILIES

__all__ = [
    "TrainConfig",
    "add_dataclass_flags",
    "config_from_args",
    "load_train_config",
    "read_config_file",
]


_Seed = Annotated[int, pydantic.Field(ge=0, lt=2**32)]
"""A seed: numpy's generators take [0, 2**32)."""


@dataclass(frozen=True)
class TrainConfig:
    """DQN training per the paper, with the options beyond it (all off by default). Every numeric
    field is finite and within the range its help text states; a value outside is refused
    naming the source, the key and the value."""

    # config files: unknown keys are errors, and so are NaN and ±inf (quadnav_onboard.config.CONFIG_DICT)
    __pydantic_config__ = CONFIG_DICT

    name: str = "paper"
    """Experiment name: the first part of the run directory name."""
    seed: _Seed = 0
    """Seed of every RNG (numpy env/replay/exploration generators and torch). Range: [0, 2**32)."""
    episodes: Annotated[int, pydantic.Field(ge=1, le=10_000_000)] = 2000
    """Training episodes (the paper: 2000); the schedules are indexed by episode.
    Range: [1, 10 000 000]."""
    train_worlds: tuple[Annotated[int, pydantic.Field(ge=1, le=10)], ...] = (1, 2, 3, 4, 5, 6, 7)
    """Paper world ids visited at random during training (never 8-10: they are held out). Range: 1..10."""
    world_files: tuple[str, ...] = ()
    """World YAML files to train on instead of ``train_worlds`` (when not empty)."""
    procedural_worlds: Annotated[int, pydantic.Field(ge=0, le=100_000)] = 0
    """Procedurally generated worlds of the paper's families added to the training set
    (sim_harness.procgen; 0 = the paper), drawn from ``procedural_seed``. Range: [0, 100 000]."""
    procedural_seed: _Seed = 20261124
    """Seed of the procedural world generator (fixed: the training set is part of the recipe).
    Range: [0, 2**32)."""
    procedural_families: tuple[str, ...] = FAMILIES
    """Families the generated training worlds cycle through, in order (sim_harness.procgen.FAMILIES;
    one named twice is drawn twice as often)."""
    n_envs: Annotated[int, pydantic.Field(ge=1, le=4096)] = 16
    """Environments stepped together (vectorised numpy). Range: [1, 4096]."""
    max_steps: Annotated[int, pydantic.Field(ge=1, le=10_000)] = 120
    """Step limit per training episode. Range: [1, 10 000]."""
    primitive_scale_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 1.0
    """Size (m per axis) of the primitives trained with (beyond the paper's sim, which trains at
    1 m and flies at 0.5 m). The moving setpoint slows and ``max_steps`` (written for 1 m) grows in
    proportion; the checkpoint records the scale, and eval flies it at that scale by default.
    Range: (0, 5]."""
    start_jitter_m: Annotated[float, pydantic.Field(ge=0, le=5)] = 0.5
    """Half-width (m) of the random start offset per axis. Range: [0, 5]."""
    reward_d_floor_m: Annotated[float, pydantic.Field(gt=0, le=5)] = 0.25
    """Floor (m) on the setpoint distance d_t that divides the paper's shaping reward (the paper
    leaves d_t -> 0 undefined; 0.25 m caps a step's reward at 2). Evaluation always reports the
    reward with the default floor. Range: (0, 5]."""
    random_start_prob: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.0
    """Share of training episodes started at a random free point along the path (0 = the paper).
    Range: [0, 1]."""
    eps_start: Annotated[float, pydantic.Field(ge=0, le=1)] = 1.0
    """ε at episode 0. Range: [0, 1]."""
    eps_end: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.1
    """ε from the end of the ramp on. Range: [0, 1]."""
    gamma_start: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.01
    """Discount γ at episode 0 (the paper grows γ). Range: [0, 1]."""
    gamma_end: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.99
    """Discount γ from the end of the ramp on. Range: [0, 1]."""
    schedule_fraction: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.8
    """Fraction of the episodes over which ε and γ ramp linearly; flat afterwards. Range: (0, 1]."""
    learning_rate: Annotated[float, pydantic.Field(gt=0, le=1)] = 1e-3
    """Adam step size (PyTorch's default; the paper states none, and 1e-4 learns more: docs/results.md).
    Range: (0, 1]."""
    lr_end: Annotated[float, pydantic.Field(gt=0, le=1)] | None = None
    """Step size at the last episode (beyond the paper): from the end of the ε/γ ramp on, it falls
    linearly from ``learning_rate`` to this; None = constant (the paper). Range: (0, 1]."""
    batch_size: Annotated[int, pydantic.Field(ge=1, le=65_536)] = 64
    """Minibatch size of one gradient update. Range: [1, 65 536]."""
    buffer_size: Annotated[int, pydantic.Field(ge=1, le=100_000_000)] = 50_000
    """Replay capacity (transitions). Range: [1, 10^8]."""
    learning_starts: Annotated[int, pydantic.Field(ge=1, le=100_000_000)] = 1_000
    """Transitions stored before the first update. Range: [1, 10^8]."""
    updates_per_step: Annotated[float, pydantic.Field(gt=0, le=1000)] = 2.0
    """Gradient updates per vectorised step (of n_envs transitions); fractions accumulate.
    Range: (0, 1000]."""
    target_update_interval: Annotated[int, pydantic.Field(ge=1, le=10_000_000)] = 250
    """Updates between hard target-network copies. Range: [1, 10^7]."""
    max_grad_norm: Annotated[float, pydantic.Field(ge=0, le=1e6)] = 10.0
    """Gradient norm clip (0 = off). Range: [0, 10^6]."""
    double_dqn: bool = False
    """Double DQN targets (beyond the paper)."""
    dueling: bool = False
    """Dueling value/advantage head (beyond the paper)."""
    n_step: Annotated[int, pydantic.Field(ge=1, le=100)] = 1
    """n-step returns (1 = the paper). Range: [1, 100]."""
    depth_history: Annotated[int, pydantic.Field(ge=1, le=32)] = 1
    """Depth frames stacked as input (1 = the paper). Range: [1, 32]."""
    position_history: Annotated[int, pydantic.Field(ge=1, le=32)] = 1
    """Relative positions stacked as input (1 = the paper). Range: [1, 32]."""
    network_width: Annotated[int, pydantic.Field(ge=1, le=4)] = 1
    """Every hidden layer of the network this many times as wide (1 = the paper's layer sizes; 2
    has about four times the parameters). An ``init_model`` of the paper's width is widened to
    it, computing what it did. Range: [1, 4]."""
    network_scale_input: bool = False
    """The network also reads the primitive scale it flies at (a fourth position sub-lane), so it
    can answer differently at 0.5 m and 1 m; every flight then tells it the scale flown. An
    ``init_model`` without the lane gets one it reads at zero weight, computing what it did.
    Imitation only (``imitation_only: true`` with DAgger): the RL updates do not carry the scale."""
    network_scale_encoding: str = "metres"
    """What the scale lane of ``network_scale_input`` reads: ``metres``, the scale itself (0.5 or
    1.0); ``log-range``, its log mapped to -1 at the smallest of ``imitation_scales`` and +1 at the
    largest, so the two scales look as different to the lane as they can (the network stores the
    range, ``NetworkConfig.scale_range_m``). One of: metres, log-range."""
    prioritized_replay: bool = False
    """Prioritised replay (beyond the paper): transitions sampled in proportion to |TD error|^α,
    the loss weighted by importance sampling (sim_harness.rl.replay.PrioritizedReplayBuffer)."""
    per_alpha: Annotated[float, pydantic.Field(ge=0, le=10)] = 0.6
    """Priority exponent α of prioritised replay (0 = uniform; Schaul et al. 2016: 0.6).
    Range: [0, 10]."""
    per_beta_start: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.4
    """Importance-sampling exponent β at episode 0; it grows linearly to 1 at the last episode.
    Range: [0, 1]."""
    shield: bool = False
    """Depth safety filter in the loop (beyond the paper): acting (greedy and random) and the TD
    target keep to the primitives it allows; the checkpoint records it, so eval and the daemon
    fly with it too (quadnav_onboard.shield)."""
    shield_clearance_m: Annotated[float, pydantic.Field(gt=0, lt=1.5)] = 0.5
    """Least clearance (m) from a primitive's predicted path to remembered depth points.
    Range: (0, 1.5), below the filter's search radius."""
    shield_memory_steps: Annotated[int, pydantic.Field(ge=1, le=64)] = 4
    """Decisions whose depth points the shield remembers. Range: [1, 64]."""
    shield_require_seen: bool = False
    """The shield also vetoes primitives into space no remembered view saw to be free."""
    shield_lookahead: str = "velocity"
    """What the shield checks past each primitive's end: "velocity" (0.3 s on at the end
    velocity) or "stop" (the stop that can follow it; ``lookahead`` of
    quadnav_onboard.shield.ShieldConfig)."""
    shield_band: bool = False
    """The shield also keeps each world's deviation limit (the episode's ``"deviation"`` stop
    round its rough path) as known space, as the flight daemon's filter does round the path it
    flies. With the filter teacher, primitives that would leave the band are labelled as vetoed."""
    dagger_iterations: Annotated[int, pydantic.Field(ge=0, le=1000)] = 0
    """Imitation of the privileged teacher before the RL episodes (beyond the paper;
    sim_harness.rl.imitation): DAgger iterations, each flying ``dagger_episodes`` episodes per
    scale of ``imitation_scales``, labelling every visited state with the teacher
    (sim_harness.rl.teacher: a search over the primitives against the true world) and fitting
    the network to all labels so far. 0 = none (the paper). Range: [0, 1000]."""
    dagger_episodes: Annotated[int, pydantic.Field(ge=1, le=1_000_000)] = 40
    """Episodes per DAgger iteration and scale. Range: [1, 10^6]."""
    dagger_beta: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.5
    """In DAgger iteration i the teacher flies a step with probability ``dagger_beta ** i``
    (iteration 0: the teacher alone), the network otherwise. Range: [0, 1]."""
    imitation_epochs: Annotated[float, pydantic.Field(gt=0, le=1000)] = 5.0
    """Passes over the aggregated labels after each DAgger iteration. Range: (0, 1000]."""
    imitation_updates: Annotated[int, pydantic.Field(ge=0, le=10_000_000)] = 0
    """Minibatch updates after each DAgger iteration, in place of ``imitation_epochs`` passes: a
    fit whose cost stays the same as the aggregate grows (the passes' cost grows with it). 0: the
    passes. Range: [0, 10^7]."""
    imitation_margin_weight: Annotated[float, pydantic.Field(ge=0, le=100)] = 0.0
    """Weight of DQfD's large-margin loss in the imitation fits (Hester et al. 2018): the label's
    first choice should lead every other Q-value by ``imitation_margin``. 0 = off.
    Range: [0, 100]."""
    imitation_margin_min_gap_m: Annotated[float, pydantic.Field(ge=0, le=10)] = 0.0
    """The large-margin loss (``imitation_margin_weight``) only in the states where the privileged
    teacher's first choice costs at least this much less than its second (metres of its cost,
    read from the soft targets as T·ln(p1 / p2)): where it is decisive, leaving near-ties to the
    soft targets. 0: in every state. Range: [0, 10]."""
    imitation_margin_against: str = "every"
    """What the large-margin loss (``imitation_margin_weight``) asks the label's first choice to
    lead: "every" other primitive (DQfD), or "holding": the primitives that do not move forward
    alone, and only in the states where the first choice moves forward, so the student does not
    hold back where its teacher goes on while the soft targets alone order the forward ones."""
    imitation_veto_weight: Annotated[float, pydantic.Field(ge=0, le=100)] = 0.0
    """Weight of a hinge on the depth safety filter's verdicts in the imitation fits: the best
    primitive the filter allowed in a labelled state should lead every one it vetoed by
    ``imitation_margin`` (needs ``shield``, whose verdicts are kept with the labels). 0 = off.
    Range: [0, 100]."""
    imitation_margin: Annotated[float, pydantic.Field(gt=0, le=100)] = 1.0
    """The lead (in Q) the large-margin loss asks of the label's first choice, and the veto hinge
    of the best allowed primitive over the vetoed ones. Range: (0, 100]."""
    imitation_lr: Annotated[float, pydantic.Field(gt=0, le=1)] = 1e-3
    """Adam step size of the imitation fits. Range: (0, 1]."""
    imitation_lr_end: Annotated[float, pydantic.Field(gt=0, le=1)] | None = None
    """The fits' step size in the last DAgger iteration, reached geometrically from
    ``imitation_lr``; None: ``imitation_lr`` throughout. Range: (0, 1]."""
    imitation_temperature_m: Annotated[float, pydantic.Field(gt=0, le=100)] = 0.1
    """Temperature (m of the teacher's cost) of the soft targets: softmax(-cost / T).
    Range: (0, 100]."""
    imitation_buffer: Annotated[int, pydantic.Field(ge=1, le=10_000_000)] = 300_000
    """Most labelled states kept (oldest overwritten past it; 6 kB each at depth
    history 3). Range: [1, 10^7]."""
    imitation_scales: tuple[Annotated[float, pydantic.Field(gt=0, le=5)], ...] = (1.0,)
    """Primitive scales (m) DAgger flies, each with its own envs (the product flies 0.5 m; the
    paper trains 1 m). Range: (0, 5] each."""
    imitation_filter_scales: tuple[Annotated[float, pydantic.Field(gt=0, le=5)], ...] = ()
    """The scales of ``imitation_scales`` at which the imitation learns the filter's lessons: the
    privileged teacher chooses among what the filter allows (``teacher_respect_filter``) and the
    hinge learns its verdicts (``imitation_veto_weight``). At the other scales the teacher plans
    on the true world alone and no verdicts are kept, so the network learns there to fly without
    the filter. The lab's layouts always learn them. Needs the privileged teacher (the filter
    teacher's labels are the filter's verdicts). Empty: every scale. Range: each one of
    ``imitation_scales``."""
    imitation_only: bool = False
    """With ``dagger_iterations`` > 0: stop after the imitation (no RL episodes; ``episodes``
    is then unused)."""
    imitation_teacher: str = "privileged"
    """Who labels DAgger's states: "privileged" (sim_harness.rl.teacher: a search over the
    primitives against the true world; cross-entropy on its soft targets) or "filter"
    (sim_harness.rl.filter_teacher: the ``init_model`` network, frozen, behind the depth safety
    filter; the student regresses its Q-values onto the expert's with the vetoed primitives pushed
    ``filter_veto_margin`` below the allowed ones; needs ``init_model`` and ``shield``)."""
    filter_veto_margin: Annotated[float, pydantic.Field(gt=0, le=100)] = 1.0
    """With the "filter" teacher: how far (in Q) below the lowest allowed primitive a vetoed one is
    labelled. Range: (0, 100]."""
    dagger_world_sampling: str = "uniform"
    """How DAgger's envs pick the world of each episode: "uniform" (every training world alike)
    or "failures" (an automatic curriculum after prioritised level replay, Jiang et al. 2021: a
    world is picked in proportion to ``dagger_world_floor`` plus its recent failure rate, the
    share of its episodes that did not reach the goal, each iteration's counts weighing half the
    next one's; a world not yet flown counts as half failed)."""
    dagger_world_floor: Annotated[float, pydantic.Field(gt=0, le=10)] = 0.1
    """With ``dagger_world_sampling`` "failures": the weight every world keeps whatever its
    failure rate (a world the student always flies well is still picked, less often).
    Range: (0, 10]."""
    dagger_noise: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.0
    """Probability that a step of DAgger's flights is a random primitive instead of the one the
    teacher or the network chose (uniform among those the flight allows: behind the filter, what
    it allows), so the teacher labels states off the paths both keep to (DART, Laskey et al.
    2017). The episodes' outcomes, and the failure curriculum's rates, include these steps.
    0 = none. Range: [0, 1]."""
    lab_dagger_noise: Annotated[float, pydantic.Field(ge=0, le=1)] | None = None
    """``dagger_noise`` in the lab layouts' flights (``lab_layouts``) alone, whose deviation limit
    and geofence end a flight that strays; unset = ``dagger_noise``. Range: [0, 1]."""
    dagger_filtered_share: Annotated[float, pydantic.Field(ge=0, le=1)] = 0.0
    """Share of DAgger's envs in which the network flies behind the depth safety filter (as the
    product does) when it is the one flying; the rest fly it alone. Needs ``shield`` when > 0.
    Range: [0, 1]."""
    lab_layouts: Annotated[int, pydantic.Field(ge=0, le=10_000)] = 0
    """Random box layouts of the lab ``lab_world`` (sim_harness.lab_layouts: 0-2 boxes near the
    path, each layout kept only if a sequence of primitives keeping the filter's margins reaches
    the goal) that DAgger also flies, under ``lab_flight_config`` as ``quadnav-sim eval
    --flight-config`` flies a world, with the D435-like depth noise on; its teacher stops at the
    flight's deviation limit and goal radius. 0 = none. Range: [0, 10 000]."""
    lab_world: str = ""
    """World file (or a shipped world's name) of the lab's room for ``lab_layouts``; its obstacles
    stay, its path is replaced by the flight config's waypoints when it sets them."""
    lab_flight_config: str = ""
    """Flight config (e.g. config/flight.yaml) whose mission, primitives, filter, deviation limit,
    geofence and altitude band the lab layouts are flown under."""
    lab_layout_seed: _Seed = 20261203
    """Seed of the lab layouts (fixed: the layouts are part of the recipe). Range: [0, 2**32)."""
    teacher_lookahead: Annotated[int, pydantic.Field(ge=1, le=2)] = 2
    """Primitives the teacher flies from a state: 1, or 2 (the second only to find dead ends).
    Range: [1, 2]."""
    teacher_margin_m: Annotated[float, pydantic.Field(gt=0, le=1)] = 0.15
    """Clearance beyond the quad's radius the teacher keeps from the true geometry.
    Range: (0, 1]."""
    teacher_grid_m: Annotated[float, pydantic.Field(ge=0.05, le=1)] = 0.25
    """Voxel size (m) of the teacher's cost-to-go field. Range: [0.05, 1]."""
    teacher_respect_filter: bool = False
    """The privileged teacher chooses among the primitives the env's depth filter allows (it
    prices the vetoed ones as crashes, where the filter allows any); needs ``shield``."""
    teacher_release_m: Annotated[float, pydantic.Field(ge=0, le=10)] = 0.0
    """With ``teacher_respect_filter``: in a state where the filter's vetoes raise the teacher's
    best cost by more than this (metres of its cost; a hold in place costs about one primitive
    length), the filter boxes it in where the true world has a way on, and the teacher chooses
    among every primitive there; those states carry no verdicts for the hinge. 0: never.
    Range: [0, 10]."""
    init_model: str = ""
    """Checkpoint whose weights start the online and target networks (fine-tuning; "" = random
    init). Its network shape must match this config's, except that this config's depth and position
    histories may be longer: the older inputs then start at zero weight
    (sim_harness.rl.widen), so the network starts as the checkpoint's and, with the "filter"
    teacher, the expert is the checkpoint's network as it was."""
    init_model_sha256: str = ""
    """sha256 (64 lowercase hex digits) the ``init_model`` file must have: a recipe that starts from a
    file that can change, such as the bundled model, then refuses to train from any other file under
    that name. "" = not checked."""
    checkpoint_every: Annotated[int, pydantic.Field(ge=1, le=10_000_000)] = 100
    """Episodes between checkpoints (model + resumable training state). Range: [1, 10^7]."""
    keep_every: Annotated[int, pydantic.Field(ge=0, le=10_000_000)] = 0
    """Episodes between model snapshots kept as ``checkpoints/ep{N}.pt`` (0 = none), so a
    checkpoint can be chosen afterwards by an evaluation on the training worlds. Range: [0, 10^7]."""
    eval_every: Annotated[int, pydantic.Field(ge=1, le=10_000_000)] | None = None
    """Episodes between greedy evaluations of the current network on the training worlds, and one
    at the end (None = none): scores in ``evals.json``/``evals.csv`` and TensorBoard, and what a
    sweep's early stopping reads. Uses its own seeded envs: training is the same with or without.
    Range: [1, 10^7]."""
    eval_trials: Annotated[int, pydantic.Field(ge=1, le=1000)] = 2
    """Episodes per training world in each of those evaluations. Range: [1, 1000]."""
    tensorboard: bool = True
    """Write TensorBoard event files to ``RUN_DIR/tb`` (needs the ``tensorboard`` extra; without
    it the run goes on and says so once)."""
    torch_threads: Annotated[int, pydantic.Field(ge=1, le=1024)] = 1
    """torch.set_num_threads (1: on a loaded 2-core machine two OpenMP threads ran ~10x slower).
    Range: [1, 1024]."""
    sim_threads: Annotated[int, pydantic.Field(ge=0, le=1024)] = 1
    """numba threads for rendering and collision (0 = numba's default, all cores; small batches
    of envs run faster on one). Range: [0, 1024]."""
    device: str = "cpu"
    """torch device of the learner ("cpu", "cuda"); the env always runs on the CPU."""
    out_dir: str = "runs"
    """Parent folder of run directories."""

    def to_dict(self) -> dict[str, Any]:
        return json.loads(json.dumps(dataclasses.asdict(self)))


def _is_sha256(text: str) -> bool:
    return len(text) == 64 and all(c in "0123456789abcdef" for c in text)


def load_train_config(mapping: Any, source: str) -> TrainConfig:
    """Validate a mapping (e.g. a run's config.json) into a :class:`TrainConfig`."""
    cfg = parse_config(TrainConfig, mapping, source)
    bad = [w for w in cfg.train_worlds if w not in range(1, 11)]
    if bad:
        raise ConfigError(f"{source}: key 'train_worlds': bad value {bad!r}: paper worlds are 1..10")
    unknown = [f for f in cfg.procedural_families if f not in FAMILIES]
    if unknown or not cfg.procedural_families:
        raise ConfigError(
            f"{source}: key 'procedural_families': bad value {list(cfg.procedural_families)!r}: "
            f"families are {', '.join(FAMILIES)}"
        )
    if cfg.imitation_teacher not in ("privileged", "filter"):
        raise ConfigError(
            f"{source}: key 'imitation_teacher': bad value {cfg.imitation_teacher!r}: "
            "teachers are privileged, filter"
        )
    if cfg.imitation_margin_against not in ("every", "holding"):
        raise ConfigError(
            f"{source}: key 'imitation_margin_against': bad value {cfg.imitation_margin_against!r}: "
            "expected 'every' or 'holding'"
        )
    if cfg.dagger_world_sampling not in ("uniform", "failures"):
        raise ConfigError(
            f"{source}: key 'dagger_world_sampling': bad value {cfg.dagger_world_sampling!r}: "
            "choices are uniform, failures"
        )
    if cfg.shield_lookahead not in LOOKAHEADS:
        raise ConfigError(
            f"{source}: key 'shield_lookahead': bad value {cfg.shield_lookahead!r}: "
            f"choices are {', '.join(LOOKAHEADS)}"
        )
    needs = cfg.imitation_teacher == "filter" and cfg.dagger_iterations > 0
    if needs and not (cfg.init_model and cfg.shield):
        raise ConfigError(
            f"{source}: key 'imitation_teacher': bad value 'filter': the filter teacher is the "
            "init_model network behind the filter: set init_model and shield: true"
        )
    if cfg.init_model_sha256 and not (cfg.init_model and _is_sha256(cfg.init_model_sha256)):
        why = "set init_model" if not cfg.init_model else "a sha256 is 64 lowercase hex digits"
        raise ConfigError(f"{source}: key 'init_model_sha256': bad value {cfg.init_model_sha256!r}: {why}")
    if cfg.dagger_filtered_share > 0 and not cfg.shield:
        raise ConfigError(
            f"{source}: key 'dagger_filtered_share': bad value {cfg.dagger_filtered_share!r}: "
            "flying behind the filter needs shield: true"
        )
    if cfg.teacher_respect_filter and not (cfg.shield and cfg.imitation_teacher == "privileged"):
        raise ConfigError(
            f"{source}: key 'teacher_respect_filter': bad value True: the privileged teacher "
            "respects the filter's verdicts: set imitation_teacher: privileged and shield: true"
        )
    if cfg.teacher_release_m > 0 and not cfg.teacher_respect_filter:
        raise ConfigError(
            f"{source}: key 'teacher_release_m': bad value {cfg.teacher_release_m!r}: the teacher "
            "leaves the filter's verdicts aside only where it respects them: set "
            "teacher_respect_filter: true"
        )
    if cfg.imitation_filter_scales and cfg.imitation_teacher != "privileged":
        raise ConfigError(
            f"{source}: key 'imitation_filter_scales': bad value {list(cfg.imitation_filter_scales)!r}: "
            "only the privileged teacher can leave the filter out; the filter teacher's labels are "
            "its verdicts (set imitation_teacher: privileged)"
        )
    stray = [s for s in cfg.imitation_filter_scales if s not in cfg.imitation_scales]
    if stray:
        raise ConfigError(
            f"{source}: key 'imitation_filter_scales': bad value {list(cfg.imitation_filter_scales)!r}: "
            f"{stray!r} not among imitation_scales {list(cfg.imitation_scales)!r}"
        )
    if cfg.imitation_veto_weight > 0 and not cfg.shield:
        raise ConfigError(
            f"{source}: key 'imitation_veto_weight': bad value {cfg.imitation_veto_weight!r}: "
            "the veto hinge learns from the filter's verdicts and needs shield: true"
        )
    if cfg.lab_layouts > 0 and not (cfg.lab_world and cfg.lab_flight_config and cfg.dagger_iterations > 0):
        raise ConfigError(
            f"{source}: key 'lab_layouts': bad value {cfg.lab_layouts!r}: the lab layouts are "
            "DAgger's: set lab_world, lab_flight_config and dagger_iterations > 0"
        )
    if cfg.imitation_margin_min_gap_m > 0 and not (
        cfg.imitation_margin_weight > 0 and cfg.imitation_teacher == "privileged"
    ):
        raise ConfigError(
            f"{source}: key 'imitation_margin_min_gap_m': bad value {cfg.imitation_margin_min_gap_m!r}: "
            "it limits the large-margin loss to the privileged teacher's decisive states: set "
            "imitation_margin_weight > 0 and imitation_teacher: privileged"
        )
    if cfg.imitation_margin_against != "every" and not cfg.imitation_margin_weight > 0:
        raise ConfigError(
            f"{source}: key 'imitation_margin_against': bad value {cfg.imitation_margin_against!r}: "
            "it says what the large-margin loss holds the first choice against: set "
            "imitation_margin_weight > 0"
        )
    if cfg.network_scale_input and not (cfg.imitation_only and cfg.dagger_iterations > 0):
        raise ConfigError(
            f"{source}: key 'network_scale_input': bad value {cfg.network_scale_input!r}: the scale "
            "is learned by imitation alone (the RL updates do not carry it): set imitation_only: "
            "true and dagger_iterations > 0"
        )
    if cfg.network_scale_encoding not in ("metres", "log-range"):
        raise ConfigError(
            f"{source}: key 'network_scale_encoding': bad value {cfg.network_scale_encoding!r}: "
            "one of 'metres', 'log-range'"
        )
    if cfg.network_scale_encoding != "metres" and not cfg.network_scale_input:
        raise ConfigError(
            f"{source}: key 'network_scale_encoding': bad value {cfg.network_scale_encoding!r}: it "
            "says how the scale lane reads the scale: set network_scale_input: true"
        )
    if cfg.network_scale_encoding == "log-range" and len(set(cfg.imitation_scales)) < 2:
        raise ConfigError(
            f"{source}: key 'network_scale_encoding': bad value {cfg.network_scale_encoding!r}: the "
            f"range is that of imitation_scales, {list(cfg.imitation_scales)!r}: give two scales or more"
        )
    if cfg.lab_dagger_noise is not None and cfg.lab_layouts == 0:
        raise ConfigError(
            f"{source}: key 'lab_dagger_noise': bad value {cfg.lab_dagger_noise!r}: it is the random "
            "steps' probability in the lab layouts' flights: set lab_layouts > 0, or leave it unset"
        )
    if cfg.dagger_iterations > 0 and not cfg.imitation_scales and cfg.lab_layouts == 0:
        raise ConfigError(
            f"{source}: key 'imitation_scales': bad value []: DAgger needs a scale to fly "
            "(or lab_layouts)"
        )
    if cfg.device != "cpu":
        import torch

        try:
            ok = torch.device(cfg.device).type == "cuda" and torch.cuda.is_available()
        except RuntimeError:
            ok = False
        if not ok:
            raise ConfigError(f"{source}: key 'device': bad value {cfg.device!r}: no such torch device here")
    return cfg


def add_dataclass_flags(parser: argparse.ArgumentParser, cls: type) -> None:
    """One ``--flag`` per field of ``cls`` (default: None = keep the config's value)."""
    hints = typing.get_type_hints(cls)
    docs = field_docstrings(cls)
    for f in dataclasses.fields(cls):
        flag = "--" + f.name.replace("_", "-")
        tp = hints[f.name]
        args = typing.get_args(tp)
        if type(None) in args and len(args) == 2:  # X | None: the flag takes an X
            tp = next(a for a in args if a is not type(None))
        default = f.default
        help_text = f"{docs.get(f.name, '')} (default: {default})".replace("%", "%%")
        if tp is bool:
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=None, help=help_text)
        elif typing.get_origin(tp) is tuple:
            item = typing.get_args(tp)[0]
            parser.add_argument(flag, type=item, nargs="+", default=None, help=help_text)
        else:
            parser.add_argument(flag, type=tp, default=None, help=help_text)


def config_from_args(args: argparse.Namespace, base: dict[str, Any] | None = None) -> TrainConfig:
    """A validated :class:`TrainConfig` from parsed flags over ``base`` (a dict of fields)."""
    data = dict(base or {})
    for f in dataclasses.fields(TrainConfig):
        value = getattr(args, f.name, None)
        if value is not None:
            data[f.name] = value
    return load_train_config(data, source="command line")


def read_config_file(path: Path) -> dict[str, Any]:
    """A run's ``config.json`` as a dict (errors name the file)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: not UTF-8, or not JSON
        raise ConfigError(f"{path}: cannot read the run config: {exc}") from None
