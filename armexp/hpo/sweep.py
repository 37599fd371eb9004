"""Hydra's multirun under ``hydra/sweeper=optuna`` (`hydra_plugins.armexp_sweeper`): checked
before it starts, its HPO run opened (or reopened) by the command line, and the sweep itself.

Each trial is launched through the configured launcher (basic, joblib, Ray, SLURM) as one train
job per seed of ``hpo.seeds``, ``n_jobs`` trials per batch; the jobs' train runs hang under the
trial's run (their ``tracking.sweep_run``), the trial runs under the HPO run. The sweeper sees
only what a job returns, at its end: it does not prune (`armexp hpo` does).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from omegaconf import OmegaConf

from armexp.config import ConfigError
from armexp.hpo import record, search, space, study

#: The sweeper's group option, and its samplers' group.
OPTION, SAMPLER_GROUP = "optuna", "hydra/sweeper/sampler"


def _given(overrides: Sequence[str], key: str) -> str | None:
    for o in overrides:
        k, eq, v = o.partition("=")
        if eq and k.lstrip("+~") == key:
            return v
    return None


def chosen(overrides: Sequence[str]) -> bool:
    return _given(overrides, "hydra/sweeper") == OPTION


@dataclass
class Plan:
    """What the command line hands the sweep: the study, and the HPO run to reopen."""

    name: str
    storage: str
    hpo_run: str | None
    tags: dict[str, str]

    def overrides(self) -> list[str]:
        return [
            f"hydra.sweeper.study_name='{self.name}'",
            f"hydra.sweeper.storage='{self.storage}'",
        ]


def prepare(stage: str, overrides: Sequence[str], search_path: Sequence[str] = ()) -> Plan:
    """Check an Optuna sweep before any job (one sentence, `ConfigError`) and find its study."""
    from mlflow.tracking import MlflowClient

    from armexp.config import compose_config, compose_unchecked
    from armexp.tracking import stage_runs, store
    from armexp.tracking.sweeps import fixed_overrides

    study.require("hydra/sweeper=optuna")
    if stage != "train":
        raise ConfigError(
            f"hydra/sweeper=optuna is not allowed with armexp {stage}: a trial is scored on the "
            "held-out success its train jobs return; use it with armexp train."
        )
    ours = [o for o in overrides if o.lstrip("+~").startswith("hydra")]
    sampler = _given(overrides, SAMPLER_GROUP)
    if sampler in study.SAMPLERS and study.SAMPLERS[sampler][1]:
        study.require(f"{SAMPLER_GROUP}={sampler}", str(study.SAMPLERS[sampler][1]))
    settings = compose_unchecked([*search_path, *ours], hydra=True).hydra.sweeper
    cfg = compose_config([*search_path, *fixed_overrides(overrides)], stage="train")
    found = space.parse(overrides, cfg)
    extra = space.from_mapping(settings.get("params") or {}, cfg, "hydra.sweeper.params.")
    found.distributions.update(extra.distributions)
    found.written.update(extra.written)
    if not found.distributions:
        raise ConfigError(
            "hydra/sweeper=optuna is not allowed without a search space: give one, e.g. "
            "'agent.learning_rate=tag(log, interval(1e-4,1e-2))', or hydra.sweeper.params."
        )
    seeds = search.check_seeds(cfg.hpo.seeds)
    search.check_checks(cfg, "hydra/sweeper=optuna")
    for end in space.ends(found):
        try:
            compose_config([*search_path, *fixed_overrides(overrides), *end], stage="train")
        except ConfigError as exc:
            raise ConfigError(f"{str(exc).rstrip('.')} (a value the search can reach).") from None
    direction = str(settings.direction)
    url = study.storage_url(cfg, settings.get("storage"))
    name = study.study_name(cfg, found, seeds, direction, settings.get("study_name"))
    the_study = study.open_study(url, name, direction, key="hydra.sweeper.study_name")
    client = MlflowClient(store.store_uri(cfg))
    stage_runs.setup(cfg)  # marks an HPO run whose process died FAILED first
    previous = search.resumable(client, the_study.user_attrs.get(study.HPO_RUN_ATTR), name)
    return Plan(name, url, previous, record.hpo_tags(name, url, "none"))


def run_sweep(sweeper: Any, arguments: list[str]) -> Any:
    """The sweep of `hydra_plugins.armexp_sweeper.optuna_sweeper.OptunaSweeper`."""
    from hydra.utils import instantiate
    from mlflow.tracking import MlflowClient

    from armexp.tracking import stage_runs, store

    cfg = sweeper.config
    hpo_run = _given(arguments, "tracking.sweep_run")
    if not hpo_run:
        raise ConfigError("hydra/sweeper=optuna is not allowed here: run it through armexp.")
    hpo_run = hpo_run.strip("'\"")
    found = space.parse(arguments, cfg)
    extra = space.from_mapping(sweeper.params or {}, cfg, "hydra.sweeper.params.")
    found.distributions.update(extra.distributions)
    found.written.update(extra.written)
    seeds = search.check_seeds(cfg.hpo.seeds)
    the_study = study.open_study(
        str(sweeper.storage), str(sweeper.study_name), str(sweeper.direction)
    )
    chosen_sampler = sweeper.sampler  # its config: built here, with the seed moved on
    study.reseed(
        the_study, lambda s: instantiate(chosen_sampler, seed=s), chosen_sampler.get("seed")
    )
    experiment_id = stage_runs.setup(cfg)
    client = MlflowClient(store.store_uri(cfg))
    the_study.set_user_attr(study.HPO_RUN_ATTR, hpo_run)
    again = study.recover(the_study)
    record.mark_interrupted(client, the_study, again)
    failed = study.retry_failed(the_study) if cfg.hpo.retry_failed else []
    about = {"study": the_study.study_name, "storage": store.hide_password(
        str(sweeper.storage)), "direction": str(sweeper.direction), "n_trials":
        int(sweeper.n_trials), "seeds": seeds, "sampler": str(chosen_sampler.get("_target_")),
        "pruner": "none", "how": "hydra/sweeper=optuna"}  # fmt: skip
    print(
        f"armexp train: study {the_study.study_name} | {study.counted(the_study)} of "
        f"{sweeper.n_trials} trials done"
        + (f", trials {', '.join(map(str, again))} interrupted: queued again" if again else "")
        + (f", failed trials {', '.join(map(str, failed))} queued again" if failed else "")
    )
    swept = "tracking.swept=[" + ",".join(f"'{k}'" for k in found.distributions) + "]"
    returns: list[Any] = []
    while (left := int(sweeper.n_trials) - study.counted(the_study)) > 0:
        trials = [the_study.ask() for _ in range(min(int(sweeper.n_jobs), left))]
        runs, jobs = [], []
        for trial in trials:
            params = found.suggest(trial)
            run_id = record.open_trial(client, experiment_id, hpo_run, trial.number, params, seeds)
            trial.set_user_attr(record.RUN_ATTR, run_id)
            runs.append(run_id)
            own = found.overrides(params)
            jobs += [(*own, f"seed={s}", f"tracking.sweep_run={run_id}", swept) for s in seeds]
        try:
            sweeper.validate_batch_is_legal(jobs)
            batch = sweeper.launcher.launch(jobs, initial_job_idx=sweeper.job_idx)
        except BaseException:
            for trial, run_id in zip(trials, runs, strict=True):
                study.interrupt(the_study, trial)
                record.close_trial(client, run_id, "INTERRUPTED", {}, None, "sweep stopped")
            raise
        sweeper.job_idx += len(batch)
        returns.append(batch)
        for i, (trial, run_id) in enumerate(zip(trials, runs, strict=True)):
            _tell(the_study, trial, run_id, client, seeds, batch[i * len(seeds) :][: len(seeds)])
        record.snapshot(client, hpo_run, the_study, found, about)
    record.snapshot(client, hpo_run, the_study, found, about)
    _results(sweeper, the_study)
    return returns


def _tell(
    the_study: Any, trial: Any, run_id: str, client: Any, seeds: Sequence[int], jobs: Sequence[Any]
) -> None:
    from hydra.core.utils import JobStatus

    success: dict[int, float] = {}
    error = None
    for seed, job in zip(seeds, jobs, strict=True):
        summary: Mapping[str, Any] = {}
        if job.status == JobStatus.COMPLETED:
            summary = getattr(job.return_value, "summary", {}) or {}
        if "final/held_out_success" not in summary:
            error = error or f"seed {seed}: " + (
                str(job._return_value).splitlines()[0] if job.status != JobStatus.COMPLETED
                else "its train run returned no held-out check"
            )  # fmt: skip
            continue
        success[seed] = float(summary["final/held_out_success"])
    value = record.end_trial(the_study, trial, client, run_id, success, error)
    if value is None:
        print(f"armexp train: trial {trial.number} failed ({error})")
        return
    print(f"armexp train: trial {trial.number} | {trial.params} | IQM {value:.3f}")


def _results(sweeper: Any, the_study: Any) -> None:
    """``optimization_results.yaml`` in the sweep folder, as Hydra's Optuna sweeper writes it."""
    from pathlib import Path

    from optuna.trial import TrialState

    if not the_study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,)):
        return
    folder = Path(str(sweeper.config.hydra.sweep.dir))
    folder.mkdir(parents=True, exist_ok=True)
    best = {"name": "optuna", "best_params": the_study.best_params,
            "best_value": the_study.best_value}  # fmt: skip
    OmegaConf.save(OmegaConf.create(best), folder / "optimization_results.yaml")
