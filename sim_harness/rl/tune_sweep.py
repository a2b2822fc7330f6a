"""Sweeps on Ray Tune: every trial one :func:`sim_harness.rl.train.train` with a TrainConfig override.

The ``sweep`` extra (``pip install "quadnav[sweep]"``). A trial trains with one torch and one numba
thread on one CPU (so trials = cores), reports the greedy scores of its network on the training
worlds every ``eval_every`` episodes (what ASHA reads to stop bad trials early), then evaluates its
final model on the ten paper worlds (train 1-7, held-out 8-10), as the process pool of
:mod:`sim_harness.rl.sweep` does. A trial that raises is recorded as failed and the others go on.

Each trial trains under ``OUT/runs/<trial id>/``; a trial started again (``Tuner.restore`` after
the sweep was killed, or a retry) resumes its own run from its last checkpoint rather than starting
over. ``OUT`` holds ``sweep.json`` (a record per trial: the pool's fields plus ``status``), ``sweep.csv``,
``best.json`` (the best model and the ``quadnav-sim ship`` command for it), ``sweep_spec.json`` and
``sweep_options.json`` (what ``--resume`` reruns) and ``tune/`` (Ray's experiment state).
"""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import structlog

from sim_harness.rl.sweep_space import SweepSpec, spec_from_mapping

__all__ = [
    "PATH_FIELDS",
    "SWEEP_EXTRA",
    "SweepOptions",
    "SweepOutcome",
    "SweepUnavailable",
    "absolute_paths",
    "best_record",
    "resume_sweep",
    "run_sweep",
    "run_trial",
    "write_tables",
]

log = structlog.get_logger(__name__)

SWEEP_EXTRA = 'pip install "quadnav[sweep]"'
"""How to install what a sweep needs (Ray Tune)."""

TUNE_DIR = "tune"
"""Ray's experiment folder inside the sweep's folder."""


class SweepUnavailable(RuntimeError):
    """Ray Tune is not installed (the ``sweep`` extra)."""


@dataclasses.dataclass(frozen=True)
class SweepOptions:
    """How a sweep runs its trials (the search itself is a :class:`SweepSpec`)."""

    out_dir: str
    """The sweep's folder (absolute; on a cluster, a folder every node sees at the same path)."""
    eval_every: int = 500
    """Episodes between the scores each trial reports while it trains (0 = only at the end)."""
    eval_trials: int = 1
    """Episodes per training world in each of those evaluations (each costs ~1 s of a trial's
    ~45 s at 2 per world: benchmarks/bench_sweep.py)."""
    final_trials: int = 10
    """Evaluation trials per paper world (1-10) of each final model (seed 1000, as the pool)."""
    scheduler: Literal["fifo", "asha"] = "fifo"
    """``fifo``: every trial runs to the end; ``asha``: ASHA stops trials behind the others."""
    metric: str = "goal_rate"
    """Score the scheduler and the best trial are judged by (maximised): ``goal_rate``,
    ``collision_free_rate``, ``distance_m`` or ``reward`` on the training worlds."""
    grace_period: int = 500
    """Episodes every trial runs before ASHA may stop it."""
    reduction_factor: int = 2
    """ASHA keeps the best 1/reduction_factor of the trials at each rung."""
    cpus_per_trial: float = 1.0
    """CPUs Ray reserves per trial: trials at once = the cluster's CPUs / this."""
    max_concurrent: int = 0
    """Most trials at once (0 = as many as the CPUs allow)."""
    address: str | None = None
    """Ray cluster to join (``ray start --head`` prints it); None = a local Ray on this machine."""
    num_cpus: int | None = None
    """CPUs of the local Ray (None = all cores); ignored with ``address``."""

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclasses.dataclass(frozen=True)
class SweepOutcome:
    """What a finished (or resumed) sweep wrote."""

    records: list[dict[str, Any]]
    sweep_json: Path
    sweep_csv: Path
    best: dict[str, Any] | None


def _require_ray(address: str | None = None) -> None:
    if address and (Path.home() / ".ray" / "auth_token").is_file():
        # a cluster from `ray start` asks for the token every node keeps in ~/.ray/auth_token; a
        # driver that joins it must say it uses one, before Ray is imported (it reads this then);
        # RAY_AUTH_MODE=disabled in the environment where the cluster runs without
        os.environ.setdefault("RAY_AUTH_MODE", "token")
    try:
        import ray  # noqa: F401
        from ray import tune  # noqa: F401
    except ImportError as exc:
        raise SweepUnavailable(
            f"a sweep needs Ray Tune, which is not installed ({exc}): {SWEEP_EXTRA}"
        ) from None


# -- the trial (runs in a Ray worker) ---------------------------------------------------------------
class _Reporter:
    """Passes each evaluation during training to Tune (a :class:`sim_harness.rl.train.TrainHook`);
    the one at the end is left to the trial's final report (a scheduler stops a trial that reaches
    its last episode, and the final evaluation must come first)."""

    def __init__(self, episodes: int) -> None:
        self.episodes = episodes

    def on_episode(self, row: dict[str, Any]) -> None:
        pass

    def on_evaluation(self, episode: int, scores: dict[str, float], model_path: Path, run_dir: Path) -> None:
        from ray import tune

        if episode < self.episodes:
            tune.report({"episodes": episode, **scores, "run_dir": str(run_dir), "final": False})


def _own_run(trial_out: Path) -> Path | None:
    """This trial's run directory from an earlier start, if any: ``train(resume=...)`` continues it
    from its last checkpoint, or from its first episode when it was stopped before one."""
    runs = sorted(p.parent for p in trial_out.glob("*/config.json"))
    return runs[-1] if runs else None


def run_trial(config: dict[str, Any], options: SweepOptions) -> None:
    """Ray's trainable: train ``config`` (TrainConfig overrides), report, evaluate the final model."""
    from ray import tune

    from sim_harness.rl.config import load_train_config
    from sim_harness.rl.sweep import evaluate_run
    from sim_harness.rl.threads import limit_threads
    from sim_harness.rl.train import train

    limit_threads(1, 1)
    trial_id = tune.get_context().get_trial_id()
    trial_out = Path(options.out_dir) / "runs" / trial_id
    overrides = {**config, "out_dir": str(trial_out), "eval_every": options.eval_every or None}
    overrides["eval_trials"] = options.eval_trials
    cfg = load_train_config(overrides, source=f"sweep trial {trial_id}")
    started = time.monotonic()
    earlier = _own_run(trial_out)
    hooks = [_Reporter(cfg.episodes)]
    if earlier is not None:
        log.info("trial_resumes", trial=trial_id, run_dir=str(earlier))
        result = train(resume=earlier, progress=False, hooks=hooks, evaluate_at_end=False)
    else:
        result = train(cfg, progress=False, hooks=hooks, evaluate_at_end=False)
    record = evaluate_run(cfg, result, options.final_trials, started)
    record["trial_id"] = trial_id
    (result.run_dir / "sweep_record.json").write_text(json.dumps(record, indent=1), encoding="utf-8")
    # the last scores: the final model's on the paper's training worlds (its full evaluation)
    scores = record["scores_train_worlds"]
    summary = {k: v for k, v in record.items() if k != "eval_rows"}
    tune.report(
        {
            "episodes": result.episodes,
            **scores,
            "run_dir": str(result.run_dir),
            "final": True,
            "record": summary,
        }
    )


# -- the driver ------------------------------------------------------------------------------------
def _init_ray(options: SweepOptions) -> None:
    import ray

    # every run directory has its own TensorBoard files and metrics: of Tune's default loggers only
    # the JSON one stays (the results read back from it); its TensorBoard one cannot write lists
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    if ray.is_initialized():
        return
    if options.address:
        ray.init(address=options.address, include_dashboard=False, configure_logging=False)
    else:
        # "local": a Ray of its own, even where `ray start` runs a cluster on this machine
        ray.init(
            address="local",
            num_cpus=options.num_cpus or os.cpu_count() or 1,
            include_dashboard=False,
            configure_logging=False,
        )


def _trainable(options: SweepOptions) -> Any:
    from ray import tune

    return tune.with_resources(
        tune.with_parameters(run_trial, options=options), {"cpu": options.cpus_per_trial}
    )


def _progress_callback(total: int, progress: bool) -> Any:
    from ray import tune
    from tqdm import tqdm

    class _Bar(tune.Callback):
        def __init__(self) -> None:
            self.bar = tqdm(total=total, desc="sweep", unit="trial", disable=not progress)

        def on_trial_complete(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
            self.bar.update(1)

        def on_trial_error(self, iteration: int, trials: list, trial: Any, **info: Any) -> None:
            log.warning("trial_failed", trial=trial.trial_id, config=trial.config)
            self.bar.update(1)

        def on_experiment_end(self, trials: list, **info: Any) -> None:
            self.bar.close()

    return _Bar()


def _tune_parts(spec: SweepSpec, options: SweepOptions, progress: bool) -> tuple[Any, Any]:
    from ray import tune
    from ray.tune.logger import JsonLoggerCallback
    from ray.tune.schedulers import ASHAScheduler, FIFOScheduler

    if options.scheduler == "asha":
        max_t = int(spec.base.get("episodes", 2000))
        scheduler: Any = ASHAScheduler(
            time_attr="episodes",
            max_t=max_t,
            grace_period=min(options.grace_period, max_t),
            reduction_factor=options.reduction_factor,
        )
    else:
        scheduler = FIFOScheduler()
    tune_config = tune.TuneConfig(
        metric=options.metric,
        mode="max",
        scheduler=scheduler,
        num_samples=spec.num_samples,
        max_concurrent_trials=options.max_concurrent or None,
    )
    run_config = tune.RunConfig(
        name=TUNE_DIR,
        storage_path=options.out_dir,
        verbose=0,
        failure_config=tune.FailureConfig(max_failures=0),
        callbacks=[JsonLoggerCallback(), _progress_callback(spec.n_trials(), progress)],
    )
    return tune_config, run_config


PATH_FIELDS = ("world_files", "init_model")
"""TrainConfig fields holding file paths: made absolute before the trials run (Ray starts each
trial in a folder of its own, and a cluster node in another machine's)."""


def _absolute(key: str, value: Any) -> Any:
    if key == "world_files":
        return tuple(str(Path(v).resolve()) for v in value)
    return str(Path(value).resolve()) if value else value


def absolute_paths(spec: SweepSpec) -> SweepSpec:
    """``spec`` with every path of :data:`PATH_FIELDS` (in base, grid and choices) made absolute."""
    base = {k: _absolute(k, v) if k in PATH_FIELDS else v for k, v in spec.base.items()}
    grid = {k: tuple(_absolute(k, v) for v in vs) if k in PATH_FIELDS else vs for k, vs in spec.grid.items()}
    sample = {
        k: dataclasses.replace(d, values=tuple(_absolute(k, v) for v in d.values)) if k in PATH_FIELDS else d
        for k, d in spec.sample.items()
    }
    return dataclasses.replace(spec, base=base, grid=grid, sample=sample)


def run_sweep(spec: SweepSpec, options: SweepOptions, *, progress: bool = True) -> SweepOutcome:
    """Run every trial of ``spec`` (ASHA may stop some early); write and return the tables."""
    _require_ray(options.address)
    from ray import tune

    spec = absolute_paths(spec)

    if options.scheduler == "asha" and options.eval_every <= 0:
        raise ValueError("ASHA needs scores during training: eval_every >= 1")
    out = Path(options.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "sweep_spec.json").write_text(json.dumps(spec.to_dict(), indent=2), encoding="utf-8")
    (out / "sweep_options.json").write_text(json.dumps(options.to_dict(), indent=2), encoding="utf-8")
    log.info("sweep_starts", name=spec.name, trials=spec.n_trials(), out=str(out), address=options.address)
    _init_ray(options)
    tune_config, run_config = _tune_parts(spec, options, progress)
    tuner = tune.Tuner(
        _trainable(options), param_space=spec.param_space(), tune_config=tune_config, run_config=run_config
    )
    return _finish(tuner.fit(), options)


def resume_sweep(out_dir: str | Path, *, progress: bool = True, address: str | None = None) -> SweepOutcome:
    """Continue a killed sweep in ``out_dir``: finished trials stay, the others run (again, each
    resuming its own training run from its last checkpoint), failed ones stay failed."""
    _require_ray(address)
    from ray import tune

    out = Path(out_dir).resolve()
    spec = spec_from_mapping(json.loads((out / "sweep_spec.json").read_text()), str(out / "sweep_spec.json"))
    options = SweepOptions(**json.loads((out / "sweep_options.json").read_text()))
    options = dataclasses.replace(options, out_dir=str(out), address=address or options.address)
    if not tune.Tuner.can_restore(str(out / TUNE_DIR)):
        raise FileNotFoundError(f"{out / TUNE_DIR}: no sweep state to resume")
    log.info("sweep_resumes", out=str(out))
    _init_ray(options)
    tuner = tune.Tuner.restore(
        str(out / TUNE_DIR),
        trainable=_trainable(options),
        resume_unfinished=True,
        resume_errored=False,
        restart_errored=False,
        param_space=spec.param_space(),
    )
    return _finish(tuner.fit(), options)


def _record_of(result: Any) -> dict[str, Any]:
    """One row of the table from a Tune result: the trial's record, or why there is none."""
    metrics = dict(result.metrics or {})
    config = dict(result.config or {})
    trial_id = metrics.get("trial_id") or Path(str(result.path)).name
    if result.error is not None:
        cause = getattr(result.error, "cause", None) or result.error  # Ray wraps the trial's error
        return {
            "status": "failed",
            "error": f"{type(cause).__name__}: {cause}"[:2000],
            "config": config,
            "trial_id": trial_id,
            "run_dir": metrics.get("run_dir"),
        }
    if not metrics.get("final"):
        return {
            "status": "stopped",
            "episodes": metrics.get("episodes"),
            "config": config,
            "trial_id": trial_id,
            "run_dir": metrics.get("run_dir"),
            "scores": {k: metrics.get(k) for k in ("goal_rate", "collision_free_rate", "distance_m")},
        }
    record = dict(metrics["record"])
    path = Path(metrics["run_dir"]) / "sweep_record.json"
    if path.is_file():  # with every evaluation row
        record = json.loads(path.read_text(encoding="utf-8"))
    return {"status": "ok", **record}


CSV_FIELDS = (
    "trial_id",
    "status",
    "name",
    "seed",
    "overrides",
    "episodes",
    "env_steps",
    "train_wall_s",
    "env_steps_per_s",
    "goal_all",
    "collision_free_all",
    "goal_train",
    "collision_free_train",
    "goal_held_out",
    "collision_free_held_out",
    "model",
    "run_dir",
    "error",
)
"""Columns of sweep.csv (rates as fractions)."""


def _csv_row(rec: dict[str, Any], swept: Sequence[str]) -> dict[str, Any]:
    cfg = rec.get("config", {})
    row: dict[str, Any] = {
        k: rec.get(k, "")
        for k in (
            "trial_id",
            "status",
            "episodes",
            "env_steps",
            "train_wall_s",
            "env_steps_per_s",
            "run_dir",
            "error",
        )
    }
    row["name"], row["seed"] = cfg.get("name", ""), cfg.get("seed", "")
    row["overrides"] = json.dumps({k: cfg.get(k) for k in swept if k in cfg})
    for part, key in (("all", "eval_all"), ("train", "eval_train_worlds"), ("held_out", "eval_held_out")):
        s = rec.get(key) or {}
        row[f"goal_{part}"] = s.get("success_rate", "")
        row[f"collision_free_{part}"] = s.get("collision_free_rate", "")
    row["model"] = str(Path(rec["run_dir"]) / "checkpoints" / "final.pt") if rec.get("status") == "ok" else ""
    return row


def write_tables(out_dir: Path, records: Sequence[dict[str, Any]], swept: Sequence[str]) -> tuple[Path, Path]:
    """``sweep.json`` (every record) and ``sweep.csv`` (one line per trial) in ``out_dir``."""
    js = out_dir / "sweep.json"
    js.write_text(json.dumps(list(records), indent=1), encoding="utf-8")
    path = out_dir / "sweep.csv"
    with path.open("w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=CSV_FIELDS)
        writer.writeheader()
        writer.writerows(_csv_row(r, swept) for r in records)
    return js, path


def best_record(records: Sequence[dict[str, Any]]) -> dict[str, Any] | None:
    """The finished trial with the best goal rate on all ten worlds (collision-free breaks ties)."""
    ok = [r for r in records if r.get("status") == "ok"]
    if not ok:
        return None
    return max(ok, key=lambda r: (r["eval_all"]["success_rate"], r["eval_all"]["collision_free_rate"]))


def _finish(grid: Any, options: SweepOptions) -> SweepOutcome:
    out = Path(options.out_dir)
    records = sorted((_record_of(r) for r in grid), key=lambda r: str(r.get("trial_id")))
    spec = json.loads((out / "sweep_spec.json").read_text())
    swept = [*spec["grid"], *spec["sample"], "seed"]
    js, csv_path = write_tables(out, records, swept)
    best = best_record(records)
    best_info = None
    if best is not None:
        model = Path(best["run_dir"]) / "checkpoints" / "final.pt"
        best_info = {
            "trial_id": best["trial_id"],
            "model": str(model),
            "config": best["config"],
            "eval_all": best["eval_all"],
            "eval_held_out": best["eval_held_out"],
            "ship": f"quadnav-sim ship --model {model} --out {out / 'best.pt'}",
        }
        (out / "best.json").write_text(json.dumps(best_info, indent=1), encoding="utf-8")
    counts = {s: sum(r["status"] == s for r in records) for s in ("ok", "stopped", "failed")}
    log.info("sweep_done", out=str(out), **counts)
    return SweepOutcome(records, js, csv_path, best_info)
