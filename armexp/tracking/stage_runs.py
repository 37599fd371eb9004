"""One MLflow run per stage execution, in the configured experiment.

Stages hand data to each other only through MLflow (docs/design.md §1). Every stage run carries:

* params: the flattened resolved config (``robot.lengths`` → ``[1.0, 0.8]``, `flatten`),
* artifact ``config.yaml``: the full resolved config,
* tags: ``armexp.stage``, what ran (`armexp.tracking.lineage`: git commit and dirty flag inside
  a git checkout, ``armexp.version.<package>``), and
* a truthful end status: FINISHED, FAILED (with ``armexp.error``) or KILLED (interrupted); a
  run whose store stopped answering is closed by the next command against it
  (`armexp.tracking.run_end`, `close_orphans`).

Where the store is: `armexp.tracking.store`; what a run logs besides its params:
`armexp.tracking.artifacts`; finding an upstream run: `armexp.tracking.lookup`.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

import mlflow
from mlflow.entities import RunTag
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf

from armexp import disk
from armexp.reads import Reads
from armexp.tracking import anchor, lineage, liveness, remote, run_end, run_names
from armexp.tracking.artifacts import log_batch
from armexp.tracking.store import artifact_root, retry, store_uri
from armexp.tracking.tags import (
    ANCHOR_TAG,
    ERROR_TAG,
    HEARTBEAT_TAG,
    INPUTS_TAG,
    KIND,
    KIND_TAG,
    PARENT_TAG,
    PROCESS_TAG,
    STAGE_TAG,
    SWEEP_TAG,
)

#: The runs that stage runs started now are nested under (`parent`), innermost last.
_parents: list[str] = []
MAX_PARAM_LENGTH = 6000

log = logging.getLogger(__name__)


def setup(cfg: DictConfig) -> str:
    """Point MLflow at the configured store and return the experiment id (created once)."""
    uri = store_uri(cfg)
    mlflow.set_tracking_uri(uri)
    client = MlflowClient(uri)
    name = str(cfg.tracking.experiment)

    tags = {KIND_TAG: KIND}
    if uri.startswith("sqlite:"):  # whether its artifacts follow the store (`anchor`)
        tags[ANCHOR_TAG] = anchor.GIVEN if cfg.tracking.artifact_root else anchor.STORE

    def get_or_create() -> str:
        exp = client.get_experiment_by_name(name)
        if exp is not None:
            anchor.check_artifact_root(cfg.tracking.artifact_root, name, exp.artifact_location)
            if KIND_TAG not in exp.tags:  # made by an older armexp or by hand; a user's kind stays
                client.set_experiment_tag(exp.experiment_id, KIND_TAG, KIND)
            return str(exp.experiment_id)
        try:
            return str(
                client.create_experiment(name, artifact_location=artifact_root(cfg), tags=tags)
            )
        except MlflowException:
            # Another job created it between our look-up and create.
            exp = client.get_experiment_by_name(name)
            if exp is None:
                raise
            return str(exp.experiment_id)

    experiment_id = retry(get_or_create)
    close_orphans(client, experiment_id)
    return experiment_id


def flatten(cfg: DictConfig | Mapping[str, Any]) -> dict[str, str]:
    """Dotted keys → string values; lists are JSON, so ``[1.0, 0.8]`` stays one param."""
    plain = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg
    out: dict[str, str] = {}

    def visit(node: Any, prefix: str) -> None:
        if isinstance(node, Mapping):
            for k, v in node.items():
                visit(v, f"{prefix}.{k}" if prefix else str(k))
        else:
            text = json.dumps(node) if isinstance(node, list) else str(node)
            out[prefix] = text[:MAX_PARAM_LENGTH]

    visit(plain, "")
    return out


@contextmanager
def parent(run_id: str) -> Iterator[None]:
    """Stage runs started inside are children of ``run_id`` (a pipeline's nested runs)."""
    _parents.append(run_id)
    try:
        yield
    finally:
        _parents.pop()


def close_orphans(client: MlflowClient, experiment_id: str) -> list[str]:
    """Mark RUNNING runs whose process stopped reporting (killed, lost power) FAILED, with
    ``armexp.error`` saying so, and name each on stderr; returns their ids. A train run among them
    can still be continued with ``train.resume``."""
    found = []
    for run in client.search_runs(
        [experiment_id], "attributes.status = 'RUNNING'", max_results=1000
    ):
        if STAGE_TAG not in run.data.tags or liveness.is_alive(run):
            continue
        age = liveness.heartbeat_age(run)
        gone = liveness.process_gone(run.data.tags.get(PROCESS_TAG))
        message = (
            f"process stopped: {run.data.tags[PROCESS_TAG]} is gone"
            if gone
            else f"process stopped: no heartbeat for {age:.0f} s"
        )
        try:
            client.set_tag(run.info.run_id, ERROR_TAG, message)
            client.set_terminated(run.info.run_id, "FAILED")
        except Exception:
            continue  # another process closes it
        stage = run.data.tags[STAGE_TAG]
        print(
            f"armexp: {stage} run {run.info.run_id} was RUNNING but its process stopped"
            + ("" if gone else f" {age:.0f} s ago")
            + "; marked FAILED"
            + (f" (continue it with train.resume={run.info.run_id})" if stage == "train" else ""),
            file=sys.stderr,
        )
        found.append(run.info.run_id)
    return found


@dataclass(frozen=True)
class StageResult:
    """What a stage's ``run(cfg)`` returns: the MLflow run it logged to and its summary (metrics,
    or a pipeline's run ids by step)."""

    run_id: str
    summary: Mapping[str, Any] = field(default_factory=dict)


@contextmanager
def stage_run(
    cfg: DictConfig,
    stage: str,
    run_name: str | None = None,
    parent_run_id: str | None = None,
    extra_tags: Mapping[str, str] | None = None,
    resume_run_id: str | None = None,
    reads: Reads | None = None,
) -> Iterator[mlflow.ActiveRun]:
    """One MLflow run for one stage execution, ended FINISHED / FAILED / KILLED truthfully.

    ``run_name`` None: `armexp.tracking.run_names.run_name` names it. ``resume_run_id`` reopens
    an existing run (its name, params and config stay as first logged). ``reads``: the stage's
    declaration of what it reads; its digest of ``cfg`` is tagged ``armexp.inputs_hash``, by
    which ``pipeline.reuse`` finds the run (`armexp.tracking.reuse`).
    """
    experiment_id = setup(cfg)
    tags = {
        STAGE_TAG: stage,
        HEARTBEAT_TAG: f"{time.time():.0f}",
        PROCESS_TAG: liveness.process_identity(),
        **(extra_tags or {}),
    }
    tags.update(lineage.lineage_tags())
    if reads is not None:
        tags[INPUTS_TAG] = reads.digest(cfg)
    sweep = OmegaConf.select(cfg, "tracking.sweep_run")
    if sweep:
        tags[SWEEP_TAG] = sweep
    parent_run_id = parent_run_id or (_parents[-1] if _parents else None) or sweep
    if parent_run_id:
        tags[PARENT_TAG] = parent_run_id
    # MLflow's start_run continues the run named by an inherited MLFLOW_RUN_ID instead of
    # starting one, whatever parent is given (mlflow #15713): a job launched from inside another
    # run (a Ray or SLURM worker, a notebook) would log into that run.
    os.environ.pop("MLFLOW_RUN_ID", None)
    if resume_run_id:
        # This process's tags go on while the run is still ended: start_run marks it RUNNING,
        # and a command starting meanwhile would find it RUNNING under its old, dead process
        # and close it as an orphan (`close_orphans`).
        client = MlflowClient(store_uri(cfg))
        resumed = [RunTag(k, v) for k, v in tags.items() if k != STAGE_TAG]
        retry(lambda: client.log_batch(resume_run_id, tags=resumed))
        run = retry(lambda: mlflow.start_run(run_id=resume_run_id, nested=bool(parent_run_id)))
    else:
        name = run_name or run_names.run_name(cfg, stage, tags)
        run = retry(
            lambda: mlflow.start_run(
                experiment_id=experiment_id,
                run_name=name,
                tags=tags,
                nested=bool(parent_run_id),
            )
        )
    try:
        if not resume_run_id:
            log_batch(run.info.run_id, params=flatten(cfg))
            mlflow.log_text(OmegaConf.to_yaml(cfg, resolve=True), "config.yaml")
        with liveness.Heartbeat(run.info.run_id, store_uri(cfg)):
            yield run
    except KeyboardInterrupt as exc:
        # Says to whoever catches it (the command line) that a run was started, and whether it
        # is marked KILLED.
        stopped = run_end.interrupted(run.info.run_id, exc)
        if stopped is exc:
            raise
        raise stopped from None
    except BaseException as exc:
        if isinstance(exc, SystemExit) and exc.code in (0, None):
            run_end.end_run(run.info.run_id, "FINISHED")
            raise
        found: Exception
        if disk.is_full(exc):
            found = run_end.fail_on_full_disk(store_uri(cfg), run.info.run_id, exc)
        elif remote.is_lost(exc):
            found = run_end.lost(str(cfg.tracking.uri), run.info.run_id, exc)
        else:
            run_end.note_error(f"{type(exc).__name__}: {exc}"[:5000])
            run_end.end_run(run.info.run_id, "FAILED")
            raise
        if found is exc:  # a nested stage's, already naming its run
            raise
        raise found from exc
    else:
        run_end.end_run(run.info.run_id, "FINISHED")
