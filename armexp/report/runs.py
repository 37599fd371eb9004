"""Which MLflow runs a report is made of, and reading them into pandas through MLflow's API.

A report starts from eval runs and follows their lineage tags upstream: ``armexp.train_run`` to
the policy's train run, ``armexp.tune_run.<label>`` to the tune run whose gains each controller
label used (eval runs made before per-label tags: ``armexp.tune_run`` for the policy's own
controller and ``armexp.pid_tune_run`` for the PID). Nothing here imports the simulation,
environment or agent code.
"""

from __future__ import annotations

import math
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mlflow
import pandas as pd
import yaml
from mlflow.entities import Run
from mlflow.tracking import MlflowClient

from armexp.config import ConfigError
from armexp.tracking import run_ids
from armexp.tracking.tags import (
    PARENT_TAG,
    PID_TUNE_RUN_TAG,
    STAGE_TAG,
    TRAIN_RUN_TAG,
    TUNE_RUN_PREFIX,
    TUNE_RUN_TAG,
)


def tune_run_ids(tags: dict[str, str]) -> list[str]:
    """Every tune run an eval run's tags name, new and old tags alike, in tag order."""
    keys = [k for k in sorted(tags) if k.startswith(TUNE_RUN_PREFIX)]
    keys += [TUNE_RUN_TAG, PID_TUNE_RUN_TAG]
    return list(dict.fromkeys(tags[k] for k in keys if tags.get(k)))


def metric_value(value: float) -> float:
    """A metric as logged: MLflow stores ±inf as ±float max, so those read back as ±inf."""
    return math.copysign(math.inf, value) if abs(value) >= 1e300 else float(value)


@dataclass
class Selection:
    """The eval runs of a report and the upstream runs they name."""

    evals: list[Run]
    trains: dict[str, Run] = field(default_factory=dict)
    tunes: dict[str, Run] = field(default_factory=dict)
    how: str = ""

    @property
    def all_runs(self) -> list[Run]:
        return [*self.evals, *self.trains.values(), *self.tunes.values()]


def select(
    client: MlflowClient,
    experiment: str,
    pipeline_run: str | None = None,
    eval_runs: list[str] | None = None,
    filter_string: str | None = None,
    store: str = "this store",
) -> Selection:
    """Eval runs by explicit ids, by pipeline parent run, by an MLflow filter, or (default) those
    of the latest pipeline run, else the latest eval run; then their lineage."""
    exp = client.get_experiment_by_name(experiment)
    if exp is None:
        raise ConfigError(
            f"the report has nothing to show: experiment '{experiment}' does not exist in this "
            "store; run `armexp eval` (after tune and train) first, or set tracking.runs_dir / "
            "tracking.uri to the store that holds your runs."
        )
    eid = exp.experiment_id
    finished_evals = f"tags.`{STAGE_TAG}` = 'eval' and attributes.status = 'FINISHED'"

    def search(filter_: str, n: int = 1000) -> list[Run]:
        return list(
            client.search_runs(
                [eid], filter_, order_by=["attributes.start_time DESC"], max_results=n
            )
        )

    def pipeline_evals(run_id: str) -> list[Run]:
        """FINISHED eval runs under a pipeline run, or under the per-seed pipelines of a study."""
        out = search(f"{finished_evals} and tags.`{PARENT_TAG}` = '{run_id}'")
        children = search(f"tags.`{STAGE_TAG}` = 'pipeline' and tags.`{PARENT_TAG}` = '{run_id}'")
        for child in sorted(children, key=lambda r: r.info.start_time):
            out += search(f"{finished_evals} and tags.`{PARENT_TAG}` = '{child.info.run_id}'")
        return out

    if pipeline_run:
        pipeline_run = run_ids.resolve(client, pipeline_run, "report.pipeline_run", store)
    if eval_runs:
        evals = []
        eval_runs = [run_ids.resolve(client, r, "report.eval_runs", store) for r in eval_runs]
        for run_id in eval_runs:
            try:
                run = client.get_run(run_id)
            except Exception:
                raise ConfigError(
                    f"report.eval_runs contains {run_id}, which is not allowed: no run with that "
                    "id exists in this store."
                ) from None
            if run.data.tags.get(STAGE_TAG) != "eval":
                raise ConfigError(
                    f"report.eval_runs contains {run_id}, which is not allowed: it is a "
                    f"{run.data.tags.get(STAGE_TAG) or 'non-armexp'} run, not an eval run."
                )
            evals.append(run)
        how = f"eval runs {', '.join(eval_runs)}"
    elif pipeline_run:
        evals = pipeline_evals(pipeline_run)
        how = f"eval runs of pipeline run {pipeline_run}"
    elif filter_string:
        evals = search(f"{finished_evals} and {filter_string}")
        how = f"eval runs matching {filter_string}"
    else:
        # The latest top-level pipeline: a study's per-seed pipelines are its children.
        pipelines = [
            r
            for r in search(f"tags.`{STAGE_TAG}` = 'pipeline'", 100)
            if PARENT_TAG not in r.data.tags
        ]
        evals = pipeline_evals(pipelines[0].info.run_id) if pipelines else []
        how = f"eval runs of the latest pipeline run {pipelines[0].info.run_id}" if evals else ""
        if not evals:
            evals = search(finished_evals, 1)
            how = "the latest finished eval run"
    if not evals:
        raise ConfigError(
            f"the report has nothing to show: {how or 'the selection'} found no FINISHED eval run "
            f"in experiment '{experiment}'; run `armexp eval` (or `armexp pipeline`) first."
        )
    selection = Selection(evals=evals, how=how)
    for ev in evals:
        tags = ev.data.tags
        upstream: list[tuple[str | None, dict[str, Run]]] = [
            (tags.get(TRAIN_RUN_TAG), selection.trains)
        ]
        upstream += [(tid, selection.tunes) for tid in tune_run_ids(tags)]
        for upstream_id, into in upstream:
            if not upstream_id or upstream_id in into:
                continue
            try:
                into[upstream_id] = client.get_run(upstream_id)
            except Exception:
                continue  # deleted upstream: the tables that need it say so
    return selection


class Reader:
    """Artifacts of runs as pandas / dicts, downloaded once into a private folder."""

    def __init__(self, tracking_uri: str) -> None:
        self.uri = tracking_uri
        self.client = MlflowClient(tracking_uri)
        self._dir = Path(tempfile.mkdtemp(prefix="armexp-report-"))
        #: Artifact roots of runs already fetched (`know`): a download by run id looks the run
        #: up again first, tens of milliseconds on every artifact.
        self._roots: dict[str, str] = {}

    def know(self, runs: list[Run]) -> None:
        """Take the artifact roots of ``runs`` from the runs themselves."""
        self._roots.update({r.info.run_id: r.info.artifact_uri for r in runs})

    def close(self) -> None:
        """Remove the downloaded artifacts."""
        shutil.rmtree(self._dir, ignore_errors=True)

    def path(self, run_id: str, artifact: str) -> Path | None:
        mlflow.set_tracking_uri(self.uri)
        into = str(self._dir / run_id)
        root = self._roots.get(run_id)
        try:
            if root is None:
                found = mlflow.artifacts.download_artifacts(
                    run_id=run_id, artifact_path=artifact, dst_path=into
                )
            else:
                found = mlflow.artifacts.download_artifacts(
                    artifact_uri=f"{root.rstrip('/')}/{artifact}", dst_path=into
                )
            return Path(found)
        except Exception:
            return None

    def frame(self, run_id: str, artifact: str) -> pd.DataFrame | None:
        path = self.path(run_id, artifact)
        if path is None:
            return None
        return pd.read_parquet(path) if artifact.endswith(".parquet") else pd.read_csv(path)

    def yaml(self, run_id: str, artifact: str) -> Any:
        path = self.path(run_id, artifact)
        return None if path is None else yaml.safe_load(path.read_text())

    def history(self, run_id: str, key: str) -> pd.DataFrame:
        points = self.client.get_metric_history(run_id, key)
        frame = pd.DataFrame([(m.step, m.value) for m in points], columns=["step", "value"])
        return frame.sort_values("step", kind="stable").reset_index(drop=True)
