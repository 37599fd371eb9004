"""The Optuna study behind an HPO: where it is stored, its name, its sampler and pruner, and
what re-running the command does to it.

Storage: an Optuna RDB database beside the MLflow store (``runs/optuna.db`` for the default
``runs/mlflow.db``), never inside it, as both keep their schema version in a table named
``alembic_version``; for a PostgreSQL store, the database ``<name>_optuna`` on the same server
(created by its administrator, as the MLflow one was); ``hpo.storage`` or
``hydra.sweeper.storage`` names another.

Resume: the study's name is derived from everything its trials' results depend on (the train
config apart from the searched keys and the seed, the search space, the seeds, the direction), so
the same command finds the same study and runs only the trials still missing up to ``n_trials``
(finished, pruned and failed trials all count). A trial left RUNNING by a process that died is
marked FAIL (user attribute ``armexp.interrupted``) and queued again with the same parameters;
it then does not count, its retry does. With ``hpo.retry_failed=true`` a trial that failed on its
own (an error in training, say one since fixed) is queued again the same way, once per command.
"""

from __future__ import annotations

import importlib.util
import json
import logging
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from omegaconf import DictConfig

from armexp.config import ConfigError

#: The study's file beside a SQLite MLflow store.
OPTUNA_DB = "optuna.db"
#: What installs Optuna and its optional samplers.
INSTALL = 'pip install "armexp[hpo]"'
#: Trial user attributes: interrupted (its process died or was stopped), the trial it retries,
#: and the study attribute naming its HPO run.
INTERRUPTED = "armexp.interrupted"
RETRY_OF = "armexp.retry_of"
HPO_RUN_ATTR = "armexp.hpo_run"
#: Samplers by name: Optuna's class and the module it needs beyond Optuna.
SAMPLERS: dict[str, tuple[str, str | None]] = {
    "tpe": ("TPESampler", None),
    "random": ("RandomSampler", None),
    "cmaes": ("CmaEsSampler", "cmaes"),
    "qmc": ("QMCSampler", "scipy"),
    "gp": ("GPSampler", "scipy"),
}
PRUNERS = ("median", "hyperband", "none")


def installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def require(what: str, module: str = "optuna") -> None:
    """``what`` (``key=value``) needs ``module``: one sentence naming the extra when it is not
    installed."""
    if not installed(module):
        needs = "Optuna" if module == "optuna" else f"the {module} package"
        if " " in what:  # a command, not a key=value
            raise ConfigError(f"{what} needs {needs}, which is not installed; {INSTALL}.")
        raise ConfigError(f"{what} is not allowed here: it needs {needs}, which is not "
                          f"installed; {INSTALL}.")  # fmt: skip


def storage_url(cfg: DictConfig, given: str | None) -> str:
    """``given``, or the database beside the MLflow store (see the module doc)."""
    if given:
        return str(given)
    from armexp.tracking import store

    uri = store.store_uri(cfg)
    if uri.startswith(("postgresql", "postgres")):
        parts = urlsplit(uri)
        return urlunsplit(parts._replace(path=f"/{parts.path.lstrip('/')}_optuna"))
    if uri.startswith("sqlite:///"):
        folder = Path(uri[len("sqlite:///") :]).parent
    else:  # an `mlflow server`: the study stays with the command that drives it
        folder = Path(str(cfg.tracking.runs_dir))
    folder.mkdir(parents=True, exist_ok=True)
    return f"sqlite:///{(folder / OPTUNA_DB).resolve()}"


def study_name(
    cfg: DictConfig, space: Any, seeds: Sequence[int], direction: str, given: str | None
) -> str:
    """``given``, or ``hpo-<agent>-<digest>`` of what the trials' results depend on."""
    if given:
        return str(given)
    import hashlib

    from armexp import reads
    from armexp.stages.train import READS

    keys = [k for k in READS.hashed if k != "seed"]
    inputs = reads.digest(cfg, keys, excluded=list(space.distributions))
    text = json.dumps([inputs, sorted(space.written.items()), list(seeds), direction])
    return f"hpo-{cfg.agent.name}-{hashlib.sha256(text.encode()).hexdigest()[:8]}"


def make_sampler(name: str, seed: int | None, key: str = "hpo.sampler.name") -> Any:
    if name not in SAMPLERS:
        raise ConfigError(f"{key}={name} is not allowed: choose one of {', '.join(SAMPLERS)}.")
    cls, module = SAMPLERS[name]
    require(f"{key}={name}")
    if module:
        require(f"{key}={name}", module)
    import optuna

    return getattr(optuna.samplers, cls)(seed=seed)


def make_pruner(spec: Mapping[str, Any], min_steps: int, max_steps: int) -> Any:
    """The pruner of ``hpo.pruner``: ``median`` (Optuna's MedianPruner), ``hyperband`` (its
    resources are environment steps, from ``min_steps`` to ``max_steps``) or ``none``."""
    import optuna

    name = str(spec["name"])
    if name == "median":
        return optuna.pruners.MedianPruner(
            n_startup_trials=int(spec["n_startup_trials"]),
            n_warmup_steps=int(spec["n_warmup_steps"]),
        )
    if name == "hyperband":
        return optuna.pruners.HyperbandPruner(
            min_resource=min_steps, max_resource=max_steps,
            reduction_factor=int(spec["reduction_factor"]),
        )  # fmt: skip
    if name == "none":
        return optuna.pruners.NopPruner()
    raise ConfigError(f"hpo.pruner.name={name} is not allowed: choose one of {', '.join(PRUNERS)}.")


def open_study(
    url: str, name: str, direction: str, sampler: Any = None, pruner: Any = None, key: str = ""
) -> Any:
    """Create the study, or load it when it exists."""
    import optuna

    optuna.logging.set_verbosity(logging.WARNING)
    try:
        # SQLite: wait for a busy database (a report reading it) instead of failing at once.
        kwargs = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else {}
        storage = optuna.storages.RDBStorage(url, engine_kwargs=kwargs)
        return optuna.create_study(
            storage=storage, study_name=name, direction=direction,  # type: ignore[arg-type]
            sampler=sampler,
            pruner=pruner, load_if_exists=True,
        )  # fmt: skip
    except ValueError as exc:  # e.g. the stored study's direction differs
        raise ConfigError(f"{key or 'the study'}={name} is not allowed: {exc}") from None
    except Exception as exc:
        from armexp.tracking import store

        first = str(exc).splitlines()[0]
        raise ConfigError(
            f"{key or 'the study storage'}={store.hide_password(url)} is not allowed: Optuna "
            f"could not open it ({first}); give a database URL armexp can write to."
        ) from None


def reseed(study: Any, make: Callable[[int | None], Any], seed: int | None) -> None:
    """A seeded sampler restarts its random stream in every process, so a resumed study would
    draw its first trials' values again: the seed moves on by the trials the study holds."""
    held = len(study.get_trials(deepcopy=False))
    study.sampler = make(None if seed is None else int(seed) + held)


def recover(study: Any) -> list[int]:
    """Trials a stopped process left RUNNING become FAIL (interrupted); every interrupted trial
    not yet retried is queued again with its parameters. Call only when no other process runs
    this study. Returns the numbers of the trials queued again."""
    from optuna.trial import TrialState

    storage = study._storage
    study_id = storage.get_study_id_from_name(study.study_name)
    for t in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, t.number)
        storage.set_trial_user_attr(trial_id, INTERRUPTED, True)
        storage.set_trial_state_values(trial_id, TrialState.FAIL)
    return _queue_again(study, interrupted=True)


def retry_failed(study: Any) -> list[int]:
    """Queue again, with its parameters, every trial that failed on its own and has no retry
    yet; the numbers queued. Call only when no other process runs this study."""
    return _queue_again(study, interrupted=False)


def _queue_again(study: Any, interrupted: bool) -> list[int]:
    """Enqueue the values of every FAIL trial, interrupted or failed on its own as asked, that
    no trial retries yet; the numbers queued."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    retried = {t.user_attrs.get(RETRY_OF) for t in trials}
    again = []
    for t in trials:
        if t.state != TrialState.FAIL or t.number in retried:
            continue
        if bool(t.user_attrs.get(INTERRUPTED)) == interrupted:
            study.enqueue_trial(t.params, user_attrs={RETRY_OF: t.number})
            again.append(t.number)
    return again


def counted(study: Any) -> int:
    """Trials that count towards ``n_trials``: finished, pruned, or failed on their own and not
    queued again (a retried trial counts through its retry)."""
    from optuna.trial import TrialState

    trials = study.get_trials(deepcopy=False)
    retried = {t.user_attrs.get(RETRY_OF) for t in trials}
    done = (TrialState.COMPLETE, TrialState.PRUNED)
    return sum(
        t.state in done
        or (
            t.state == TrialState.FAIL
            and not t.user_attrs.get(INTERRUPTED)
            and t.number not in retried
        )
        for t in trials
    )


def claimed(study: Any) -> int:
    """Trials that count, and those running now (in this process or another of the search)."""
    from optuna.trial import TrialState

    running = len(study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)))
    return counted(study) + running


def interrupt(study: Any, trial: Any) -> None:
    """Mark a trial stopped by a signal: FAIL, interrupted (queued again on resume)."""
    from optuna.trial import TrialState

    trial.set_user_attr(INTERRUPTED, True)
    study.tell(trial, state=TrialState.FAIL)
