"""A multirun's jobs listed before any runs, and the MLflow run that groups them.

`sweep_combinations` expands a sweep with Hydra's public override parser (``Override`` and its
``sweep_string_iterator``) the way Hydra's basic sweeper does, so every job's config can be
composed and checked before the first job starts.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Sequence
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override
from hydra.errors import HydraException

from armexp.tracking.tags import (
    ERROR_TAG,
    HEARTBEAT_TAG,
    PARENT_TAG,
    PROCESS_TAG,
    STAGE_TAG,
    SWEEP_STAGE_TAG,
    SWEEP_TAG,
)


def _ours(overrides: Sequence[str]) -> list[Override]:
    """The parsed overrides of armexp's config: Hydra's own (``hydra/launcher=…``,
    ``hydra.sweeper.…``) configure Hydra, which checks them when it starts."""
    parsed = OverridesParser.create().parse_overrides(list(overrides))
    return [o for o in parsed if not o.is_hydra_override()]


def sweep_combinations(overrides: Sequence[str]) -> list[list[str]]:
    """Every job's overrides of a sweep, as Hydra's basic sweeper forms them: the cartesian
    product of each override's values (``a=1,2``, ``choice(…)``, ``range(…)``). Sweeps that
    cannot be listed here (an interval for an optimising sweeper, a glob over a config group)
    are left to the sweeper, which checks them when it runs. Hydra's own overrides are left out
    (see `_ours`)."""
    axes: list[list[str]] = []
    for override in _ours(overrides):
        if not override.is_sweep_override():
            axes.append([str(override.input_line)])
            continue
        key = override.get_key_element()
        try:
            axes.append([f"{key}={value}" for value in override.sweep_string_iterator()])
        except HydraException:
            continue
    return [list(job) for job in itertools.product(*axes)]


def swept_keys(overrides: Sequence[str]) -> set[str]:
    """The keys a sweep varies (``tuner.pa`` of ``tuner.pa=0.1,0.25``); an override that does
    not parse on its own is skipped."""
    parser = OverridesParser.create()
    keys = set()
    for text in overrides:
        try:
            (override,) = parser.parse_overrides([text])
        except HydraException:
            continue
        if override.is_sweep_override() and not override.is_hydra_override():
            keys.add(override.get_key_element().lstrip("+~"))
    return keys


def fixed_overrides(overrides: Sequence[str]) -> list[str]:
    """The overrides every job of a sweep shares."""
    return [str(o.input_line) for o in _ours(overrides) if not o.is_sweep_override()]


def open_sweep(
    stage: str,
    overrides: Sequence[str],
    search_path: Sequence[str] = (),
    reopen: str | None = None,
    tags: dict[str, str] | None = None,
    run_name: str | None = None,
) -> tuple[Any, str, Any]:
    """A parent run that groups the jobs of ``armexp <stage> -m …`` in the MLflow UI; its id
    reaches every job as ``tracking.sweep_run``. ``reopen``: a stopped sweep run to continue
    instead (an Optuna sweep resuming its study); ``tags`` and ``run_name``: its own. (MLflow
    is imported here, not before: the checks before a sweep do not need it.)"""
    from mlflow.tracking import MlflowClient

    from armexp.config import compose_config
    from armexp.tracking import liveness, stage_runs, store
    from armexp.tracking.run_end import clear_error

    cfg = compose_config([*search_path, *fixed_overrides(overrides)])
    experiment_id = stage_runs.setup(cfg)
    client = MlflowClient(store.store_uri(cfg))
    own = {
        STAGE_TAG: "sweep",
        SWEEP_STAGE_TAG: stage,
        HEARTBEAT_TAG: f"{time.time():.0f}",
        PROCESS_TAG: liveness.process_identity(),
        **(tags or {}),
    }
    if reopen:
        sweep_id = reopen
        store.retry(lambda: client.update_run(reopen, status="RUNNING"))
        for key, value in own.items():
            store.retry(lambda k=key, v=value: client.set_tag(reopen, k, v))  # type: ignore[misc]
        clear_error(client, reopen)
        print(f"armexp {stage}: sweep run {sweep_id} continues with the jobs of this multirun")
    else:
        name = run_name or f"sweep-{stage}"
        run = store.retry(lambda: client.create_run(experiment_id, run_name=name, tags=own))
        sweep_id = run.info.run_id
        client.log_param(sweep_id, "overrides", " ".join(overrides)[:6000])
        print(f"armexp {stage}: sweep run {sweep_id} groups the jobs of this multirun")
    return client, sweep_id, liveness.Heartbeat(sweep_id, store.store_uri(cfg))


def close_sweep(sweep: tuple[Any, str, Any], status: str) -> None:
    from armexp.tracking import stage_runs, store

    client, sweep_id, _ = sweep
    if status != "FINISHED":
        experiment_id = client.get_run(sweep_id).info.experiment_id
        if status == "FAILED":
            # A job whose worker died (SIGKILL, OOM) left its runs RUNNING: FAILED, naming the
            # process that is gone.
            store.retry(lambda: stage_runs.close_orphans(client, experiment_id))
        # Jobs stopped with the sweep (Ctrl-C reaches its workers too) end as the sweep did.
        running = client.search_runs(
            [experiment_id],
            f"tags.`{SWEEP_TAG}` = '{sweep_id}' and attributes.status = 'RUNNING'",
            max_results=1000,
        )
        for run in running:
            run_id = str(run.info.run_id)

            def stop(rid: str = run_id) -> None:
                client.set_tag(rid, ERROR_TAG, "sweep stopped")
                client.set_terminated(rid, "KILLED")

            store.retry(stop)
        jobs = client.search_runs(
            [experiment_id], f"tags.`{PARENT_TAG}` = '{sweep_id}'", max_results=10000
        )
        if not jobs and status == "FAILED":
            # Hydra stopped before any job had a run (its own error was printed): an empty
            # sweep run would only be clutter, so it goes to MLflow's deleted runs.
            store.retry(lambda: client.set_terminated(sweep_id, status))
            store.retry(lambda: client.delete_run(sweep_id))
            return
        unfinished = sum(r.info.status != "FINISHED" for r in jobs)
        why = "interrupted" if status == "KILLED" else "a job failed"
        reason = f"{why}: {unfinished} of its {len(jobs)} jobs did not finish"
        store.retry(lambda: client.set_tag(sweep_id, ERROR_TAG, reason))
    store.retry(lambda: client.set_terminated(sweep_id, status))
