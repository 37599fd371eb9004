"""An HPO in MLflow: the HPO run that records the study, and one trial run per trial under it.

The trial run (stage ``trial``) holds the trial's values as params, each seed's final held-out
success (``hpo/success_s<seed>``) and the objective (``hpo/objective``); the seeds' train runs
hang under it. After every trial the HPO run gets the study as files (``hpo/trials.csv``,
``hpo/space.json``, ``hpo/study.json``) and its counts as metrics, so the report reads an HPO
from the MLflow store alone (`armexp.report.hpo`), without the Optuna database.
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from armexp.tracking import liveness, store
from armexp.tracking.tags import (
    HEARTBEAT_TAG,
    HPO_PRUNER_TAG,
    HPO_STORAGE_TAG,
    HPO_STUDY_TAG,
    PARENT_TAG,
    PROCESS_TAG,
    STAGE_TAG,
    TRIAL_NUMBER_TAG,
    TRIAL_STATE_TAG,
)

#: The artifact folder of an HPO run, and its files.
FOLDER = "hpo"
TRIALS_FILE, SPACE_FILE, STUDY_FILE = "trials.csv", "space.json", "study.json"
#: The trials with their values typed (the report rebuilds the study from it).
TRIALS_JSON = "trials.json"
#: The trial's MLflow run, as a trial user attribute.
RUN_ATTR = "armexp.run"
#: The trial's metric: what the study optimises.
OBJECTIVE = "hpo/objective"


def objective(values: Sequence[float]) -> float:
    """A trial's value: the interquartile mean of its seeds' final held-out success rates."""
    from armexp.report.stats import iqm

    return float(iqm(np.asarray(values, dtype=float)))


def hpo_tags(study: str, storage: str, pruner: str) -> dict[str, str]:
    return {
        STAGE_TAG: "hpo",
        HPO_STUDY_TAG: study,
        HPO_STORAGE_TAG: store.hide_password(storage),
        HPO_PRUNER_TAG: pruner,
    }


def open_trial(
    client: Any, experiment_id: str, hpo_run: str, number: int, params: Mapping[str, Any],
    seeds: Sequence[int],
) -> str:  # fmt: skip
    """A RUNNING trial run under the HPO run; its params are the trial's values."""
    from armexp.tracking import artifacts, store

    run = store.retry(
        lambda: client.create_run(
            experiment_id,
            run_name=f"trial-{number}",
            tags={
                STAGE_TAG: "trial",
                PARENT_TAG: hpo_run,
                TRIAL_NUMBER_TAG: str(number),
                HEARTBEAT_TAG: f"{time.time():.0f}",
                PROCESS_TAG: liveness.process_identity(),
            },
        )
    )
    run_id = str(run.info.run_id)
    shown = {k: str(v) for k, v in params.items()}
    artifacts.log_batch(run_id, params={**shown, "hpo.seeds": json.dumps(list(seeds))},
                       client=client)  # fmt: skip
    return run_id


def close_trial(
    client: Any, run_id: str, state: str, success: Mapping[int, float], value: float | None,
    error: str | None = None,
) -> None:  # fmt: skip
    """End a trial run: FINISHED for a complete or pruned trial, FAILED or KILLED otherwise."""
    from mlflow.entities import Metric

    from armexp.tracking import artifacts, store
    from armexp.tracking.run_end import clear_error
    from armexp.tracking.tags import ERROR_TAG

    now = int(time.time() * 1000)
    metrics = [Metric(f"hpo/success_s{s}", float(v), now, 0) for s, v in success.items()]
    if value is not None:
        metrics.append(Metric(OBJECTIVE, float(value), now, 0))
    artifacts.log_batch(run_id, metrics, client=client)
    store.retry(lambda: client.set_tag(run_id, TRIAL_STATE_TAG, state))
    if error:
        store.retry(lambda: client.set_tag(run_id, ERROR_TAG, error[:5000]))
    status = {"COMPLETE": "FINISHED", "PRUNED": "FINISHED", "INTERRUPTED": "KILLED"}
    if status.get(state) == "FINISHED":
        clear_error(client, run_id)
    store.retry(lambda: client.set_terminated(run_id, status.get(state, "FAILED")))


def end_trial(
    study: Any, trial: Any, client: Any, run_id: str, success: Mapping[int, float],
    error: str | None = None,
) -> float | None:  # fmt: skip
    """Tell the study how a trial ended and close its run: FAIL with ``error``, or COMPLETE with
    the objective of its seeds' ``success`` (returned)."""
    from optuna.trial import TrialState

    if error is not None:
        study.tell(trial, state=TrialState.FAIL)
        close_trial(client, run_id, "FAIL", success, None, error)
        return None
    value = objective(list(success.values()))
    study.tell(trial, value)
    close_trial(client, run_id, "COMPLETE", success, value)
    return value


def mark_interrupted(client: Any, study: Any, numbers: Sequence[int]) -> None:
    """Tag the trial runs of trials a stopped process left behind (`armexp.hpo.study.recover`)."""
    from armexp.tracking import store

    for t in study.get_trials(deepcopy=False):
        run_id = t.user_attrs.get(RUN_ATTR)
        if t.number in numbers and run_id:
            store.retry(lambda r=run_id: client.set_tag(r, TRIAL_STATE_TAG, "INTERRUPTED"))  # type: ignore[misc]


def trial_records(study: Any) -> list[dict[str, Any]]:
    """One record per trial: number, state, value (a pruned trial's: its last check), its
    values (``params``), when it ran, and its trial run."""
    from armexp.hpo.study import INTERRUPTED, RETRY_OF

    rows = []
    for t in study.get_trials(deepcopy=False):
        start, end = t.datetime_start, t.datetime_complete
        value = t.value
        if value is None and t.intermediate_values:
            value = t.intermediate_values[max(t.intermediate_values)]
        rows.append({
            "number": t.number,
            "state": t.state.name,
            "value": value,
            "params": dict(t.params),
            "started": start.isoformat() if start else None,
            "duration_s": (end - start).total_seconds() if start and end else None,
            "retry_of": t.user_attrs.get(RETRY_OF),
            "interrupted": bool(t.user_attrs.get(INTERRUPTED, False)),
            "run_id": t.user_attrs.get(RUN_ATTR),
        })  # fmt: skip
    return rows


def trials_frame(study: Any) -> Any:
    """`trial_records` as a table, the values as ``params.<key>`` columns."""
    import pandas as pd

    rows = []
    for r in trial_records(study):
        params = r.pop("params")
        rows.append({**r, **{f"params.{k}": v for k, v in params.items()}})
    return pd.DataFrame(rows)


def snapshot(client: Any, hpo_run: str, study: Any, space: Any, about: Mapping[str, Any]) -> None:
    """The study's trials, space and settings as files of the HPO run, its counts as metrics."""
    from mlflow.entities import Metric
    from optuna.distributions import distribution_to_json
    from optuna.trial import TrialState

    from armexp.tracking import artifacts, store

    frame = trials_frame(study)
    spaces = {k: json.loads(distribution_to_json(d)) for k, d in space.distributions.items()}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        frame.to_csv(folder / TRIALS_FILE, index=False)
        (folder / TRIALS_JSON).write_text(json.dumps(trial_records(study), default=str))
        (folder / SPACE_FILE).write_text(json.dumps({"space": spaces, "written": space.written,
                                                     "fixed": space.fixed}, indent=1))  # fmt: skip
        (folder / STUDY_FILE).write_text(json.dumps(dict(about), indent=1, default=str))
        for name in (TRIALS_FILE, TRIALS_JSON, SPACE_FILE, STUDY_FILE):
            store.retry(lambda n=name: client.log_artifact(hpo_run, str(folder / n), FOLDER))  # type: ignore[misc]
    states = [t.state for t in study.get_trials(deepcopy=False)]
    now = int(time.time() * 1000)
    counts = {
        "hpo/trials_complete": states.count(TrialState.COMPLETE),
        "hpo/trials_pruned": states.count(TrialState.PRUNED),
        "hpo/trials_failed": states.count(TrialState.FAIL),
    }
    metrics = [Metric(k, float(v), now, 0) for k, v in counts.items()]
    if counts["hpo/trials_complete"]:
        metrics.append(Metric("hpo/best_value", float(study.best_value), now, 0))
    artifacts.log_batch(hpo_run, metrics, client=client)
