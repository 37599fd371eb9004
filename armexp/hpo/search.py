"""`armexp hpo`'s loop: trials asked of an Optuna study one at a time, each training its seeds
in this process (so the held-out checks can prune it), until the study holds ``hpo.n_trials``."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import mlflow
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf, open_dict

from armexp.config import ConfigError
from armexp.hpo import parallel, record, space, study
from armexp.tracking import liveness, stage_runs, store
from armexp.tracking.tags import STOP_REASON_TAG


def check_seeds(seeds: Sequence[Any], key: str = "hpo.seeds") -> list[int]:
    """At least two distinct seeds: a trial's value is their interquartile mean."""
    out = [int(s) for s in seeds]
    if len(set(out)) < 2 or len(set(out)) != len(out):
        raise ConfigError(
            f"{key}={out} is not allowed: give two or more distinct seeds (a trial's value is "
            "the interquartile mean of their held-out success)."
        )
    return out


def check_checks(cfg: DictConfig, how: str) -> None:
    """Trials are scored on the held-out checks, which ``train.eval_every`` = 0 turns off."""
    if int(cfg.train.eval_every) < 1:
        raise ConfigError(
            f"train.eval_every={cfg.train.eval_every} is not allowed with {how}: a trial is scored "
            "on the held-out checks during training; give a number of environment steps ≥ 1."
        )


def resumable(client: MlflowClient, run_id: str | None, name: str) -> str | None:
    """The study's HPO run to continue, None when it has none; one sentence when another
    process still runs it."""
    if not run_id:
        return None
    try:
        run = client.get_run(run_id)
    except Exception:
        return None  # deleted from the store: a new HPO run records the study from now on
    if liveness.is_alive(run):
        raise ConfigError(
            f"the study {name} is not allowed to run twice at once: its HPO run {run_id} is "
            f"still running in another process (last heartbeat {liveness.heartbeat_age(run):.0f}"
            " s ago); wait for it to end or stop it first."
        )
    return run_id


def run(cfg: DictConfig) -> stage_runs.StageResult:
    from armexp.stages.train import step_budget

    h = cfg.hpo
    study.require("armexp hpo")
    found = space.from_mapping(h.params, cfg, "hpo.params.")
    seeds = check_seeds(h.seeds)
    check_checks(cfg, "armexp hpo")
    budget = step_budget(cfg)
    pruner = study.make_pruner(h.pruner, int(cfg.train.eval_every), budget * len(seeds))
    url = study.storage_url(cfg, h.storage)
    name = study.study_name(cfg, found, seeds, "maximize", h.study_name)
    me = parallel.role()
    n_jobs = int(h.n_jobs)
    line = parallel.command_line() if n_jobs > 1 and not me.is_worker else []
    the_study = study.open_study(url, name, "maximize", None, pruner, "hpo.study_name")
    # Each process its own random stream: workers started together would draw the same values.
    seed = None if h.sampler.seed is None else int(h.sampler.seed) + 1_000_003 * me.index
    study.reseed(the_study, lambda s: study.make_sampler(str(h.sampler.name), s), seed)
    experiment_id = stage_runs.setup(cfg)  # marks an HPO run whose process died FAILED first
    client = MlflowClient(store.store_uri(cfg))
    if me.is_worker:
        assert me.hpo_run is not None
        print(f"hpo: worker {me.index} of study {name} | HPO run {me.hpo_run}")
        while me.owner_alive() and study.claimed(the_study) < int(h.n_trials):
            _trial(cfg, the_study, found, seeds, budget, client, experiment_id, me.hpo_run)
        return stage_runs.StageResult(me.hpo_run, _summary(the_study))
    previous = resumable(client, the_study.user_attrs.get(study.HPO_RUN_ATTR), name)
    again = study.recover(the_study)
    record.mark_interrupted(client, the_study, again)
    failed = study.retry_failed(the_study) if h.retry_failed else []
    tags = record.hpo_tags(name, url, str(h.pruner.name))
    with stage_runs.stage_run(
        cfg, "hpo", run_name=h.run_name or name, extra_tags=tags, resume_run_id=previous
    ) as active:
        hpo_run = active.info.run_id
        the_study.set_user_attr(study.HPO_RUN_ATTR, hpo_run)
        done = study.counted(the_study)
        print(
            f"hpo: study {name} in {store.hide_password(url)} | HPO run {hpo_run} | "
            f"{done} of {h.n_trials} trials done"
            + (f", trials {', '.join(map(str, again))} interrupted: queued again" if again else "")
            + (f", failed trials {', '.join(map(str, failed))} queued again" if failed else "")
        )
        about = {"study": name, "storage": store.hide_password(url),
                 "direction": "maximize", "n_trials": int(h.n_trials), "seeds": seeds,
                 "sampler": str(h.sampler.name), "pruner": str(h.pruner.name),
                 "budget_steps": budget, "n_jobs": n_jobs, "how": "armexp hpo"}  # fmt: skip
        record.snapshot(client, hpo_run, the_study, found, about)
        workers = parallel.start(n_jobs, hpo_run, line) if line else parallel.Workers()
        try:
            while study.claimed(the_study) < int(h.n_trials):
                _trial(cfg, the_study, found, seeds, budget, client, experiment_id, hpo_run)
                record.snapshot(client, hpo_run, the_study, found, about)
        except BaseException:
            workers.stop()
            raise
        errors = [i for i, code in enumerate(workers.join(), 1) if code != 0]
        if errors:
            print(f"hpo: workers {errors} ended with an error (their Hydra logs say why)")
        record.snapshot(client, hpo_run, the_study, found, about)
        summary = _summary(the_study)
        best = summary.get("hpo/best_value")
        print(
            f"hpo: run {hpo_run} | {int(summary['hpo/trials'])} trials "
            f"({int(summary['hpo/trials_pruned'])} pruned, {int(summary['hpo/trials_failed'])} "
            "failed)"
            + (
                f" | best trial {the_study.best_trial.number}: {best:.3f} "
                f"{the_study.best_trial.params}"
                if best is not None
                else ""
            )
        )
        return stage_runs.StageResult(hpo_run, summary)


def _summary(the_study: Any) -> dict[str, float]:
    from optuna.trial import TrialState

    states = [t.state for t in the_study.get_trials(deepcopy=False)]
    out = {
        "hpo/trials": float(len(states)),
        "hpo/trials_pruned": float(states.count(TrialState.PRUNED)),
        "hpo/trials_failed": float(states.count(TrialState.FAIL)),
    }
    if TrialState.COMPLETE in states:
        out["hpo/best_value"] = float(the_study.best_value)
    return out


def trial_config(cfg: DictConfig, overrides: list[str], seed: int) -> DictConfig:
    """The train config of one seed of a trial: the command's own overrides, then the trial's."""
    from hydra.core.hydra_config import HydraConfig

    from armexp.config import compose_config

    swept = "tracking.swept=[" + ",".join(f"'{k}'" for k in _keys(overrides)) + "]"
    if HydraConfig.initialized():
        task = [o for o in HydraConfig.get().overrides.task if not o.startswith("seed=")]
        return compose_config([*task, *overrides, f"seed={seed}", swept], stage="train")
    from hydra.core.override_parser.overrides_parser import OverridesParser

    out = copy.deepcopy(cfg)  # called outside a Hydra app: plain keys only
    with open_dict(out):
        for o in OverridesParser.create().parse_overrides([*overrides, f"seed={seed}"]):
            OmegaConf.update(out, o.key_or_group, o.value())
    return out


def _keys(overrides: list[str]) -> list[str]:
    return [o.partition("=")[0] for o in overrides]


def _tag_pruned(client: MlflowClient, train_run: str) -> None:
    store.retry(lambda: client.set_tag(train_run, STOP_REASON_TAG, "pruned"))


def _trial(
    cfg: DictConfig, the_study: Any, found: space.Space, seeds: list[int], budget: int,
    client: MlflowClient, experiment_id: str, hpo_run: str,
) -> None:  # fmt: skip
    from optuna.trial import TrialState

    from armexp.hpo.pruning import ReportChecks
    from armexp.stages import train

    trial = the_study.ask()
    params = found.suggest(trial)
    run_id = record.open_trial(client, experiment_id, hpo_run, trial.number, params, seeds)
    trial.set_user_attr(record.RUN_ATTR, run_id)
    trial.set_user_attr(parallel.PROCESS_ATTR, parallel.role().index)
    print(f"hpo: trial {trial.number} | {params}")
    overrides = [f"{k}={space._text(v)}" for k, v in params.items()]
    success: dict[int, float] = {}
    try:
        for i, seed in enumerate(seeds):
            seed_cfg = trial_config(cfg, overrides, seed)
            prune = ReportChecks(trial, i * budget)
            # The trial run active: MLflow hangs a nested run under the active one.
            with mlflow.start_run(run_id=run_id, nested=True), stage_runs.parent(run_id):
                result = train.run(seed_cfg, addons=[prune])
            success[seed] = float(result.summary.get("final/held_out_success", float("nan")))
            if prune.pruned_at is not None:
                _tag_pruned(client, result.run_id)
                the_study.tell(trial, state=TrialState.PRUNED)
                record.close_trial(client, run_id, "PRUNED", success, None)
                print(f"hpo: trial {trial.number} pruned at step {prune.pruned_at}")
                return
    except ConfigError:
        record.end_trial(the_study, trial, client, run_id, success, "bad config")
        raise
    except KeyboardInterrupt:
        study.interrupt(the_study, trial)
        record.close_trial(client, run_id, "INTERRUPTED", success, None, "interrupted")
        raise
    except Exception as exc:
        why = f"{type(exc).__name__}: {exc}".splitlines()[0]
        record.end_trial(the_study, trial, client, run_id, success, why)
        print(f"hpo: trial {trial.number} failed ({why}); going on")
        return
    value = record.end_trial(the_study, trial, client, run_id, success)
    print(f"hpo: trial {trial.number} | held-out success by seed {success} | IQM {value:.3f}")
