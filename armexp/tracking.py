"""The MLflow backbone: store location, one run per stage, artifacts, and run look-up.

Stages hand data to each other only through MLflow (docs/design.md §1). Every stage run carries:

* params: the flattened resolved config (``robot.lengths`` → ``[1.0, 0.8]``),
* artifact ``config.yaml``: the full resolved config,
* tags: ``armexp.stage``, what ran (`armexp.lineage`: git commit and dirty flag inside a git
  checkout, ``armexp.version.<package>``), and
* a truthful end status: FINISHED, FAILED (with ``armexp.error``) or KILLED (interrupted); a
  run whose store stopped answering is closed by the next command against it (`armexp.run_end`).

The default store is ``sqlite:///<runs_dir>/mlflow.db`` with artifacts under
``<runs_dir>/artifacts``, both relative to the directory armexp is started in.
"""

from __future__ import annotations

import atexit
import json
import logging
import os
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import mlflow
from mlflow.entities import Metric, Param, Run
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf

from armexp import anchor, disk, lineage, liveness, remote, run_end, run_ids, run_names, store
from armexp.config import ConfigError
from armexp.reads import Reads
from armexp.tags import ERROR_TAG, INPUTS_TAG, PARENT_TAG, STAGE_TAG, SWEEP_TAG

#: MLflow's experiment kind: the UIs that read it open a "Machine learning" experiment on its runs
#: table, not on the GenAI overview of traces, which armexp never logs.
KIND_TAG, KIND = "mlflow.experimentKind", "custom_model_development"
_parents: list[str] = []
MAX_PARAM_LENGTH = 6000

log = logging.getLogger(__name__)
logging.getLogger("alembic").setLevel(logging.WARNING)
# MLflow logs each database error it then raises (a lock, a full disk); armexp reports the error.
logging.getLogger("mlflow.store.db.utils").setLevel(logging.CRITICAL)


def store_uri(cfg: DictConfig, reading: bool = False) -> str:
    """The tracking URI: ``tracking.uri`` or the SQLite file under ``tracking.runs_dir``; a
    SQLite store is created (or migrated) under a lock the first time this process uses it.
    ``reading``: for a command that only reads, which creates nothing (`store.open_once`).
    Requests to a server or database are held to ``tracking.timeout_s`` (`armexp.remote`)."""
    remote.configure(float(OmegaConf.select(cfg, "tracking.timeout_s", default=remote.DEFAULT_S)))
    if cfg.tracking.uri:
        uri = str(cfg.tracking.uri)
        if f":{remote.HIDDEN}@" in uri:
            real = os.environ.get(store.SECRET_URI_ENV, "")
            if store.hide_password(real) != uri:
                raise ConfigError(
                    f"tracking.uri={uri} is not allowed here: its password is hidden and this "
                    f"process was not given it ({store.SECRET_URI_ENV}); pass tracking.uri with "
                    "the password on the armexp command line."
                )
            uri = real
    else:
        runs = Path(cfg.tracking.runs_dir).resolve()
        if not reading:
            runs.mkdir(parents=True, exist_ok=True)
        uri = f"sqlite:///{runs / 'mlflow.db'}"
    store.open_once(uri, reading)
    return uri


def artifact_root(cfg: DictConfig) -> str | None:
    """Where a new experiment stores artifacts (None: the server decides): a SQLite store's
    ``artifacts`` folder beside its database unless ``tracking.artifact_root`` says otherwise."""
    if cfg.tracking.artifact_root:
        return str(cfg.tracking.artifact_root)
    uri = str(cfg.tracking.uri or "")
    if uri and not uri.startswith("sqlite:///"):
        return None
    db = Path(uri[len("sqlite:///") :]) if uri else Path(cfg.tracking.runs_dir) / "mlflow.db"
    return anchor.store_artifacts(db.resolve()).as_uri()


is_lock = store.is_locked
retry = store.retry
RunInterrupted = run_end.RunInterrupted


def setup(cfg: DictConfig) -> str:
    """Point MLflow at the configured store and return the experiment id (created once)."""
    uri = store_uri(cfg)
    mlflow.set_tracking_uri(uri)
    client = MlflowClient(uri)
    name = str(cfg.tracking.experiment)

    tags = {KIND_TAG: KIND}
    if uri.startswith("sqlite:"):  # whether its artifacts follow the store (`armexp.anchor`)
        tags[anchor.ANCHOR_TAG] = anchor.GIVEN if cfg.tracking.artifact_root else anchor.STORE

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
        gone = liveness.process_gone(run.data.tags.get(liveness.PROCESS_TAG))
        message = (
            f"process stopped: {run.data.tags[liveness.PROCESS_TAG]} is gone"
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

    ``run_name`` None: `armexp.run_names.run_name` names it. ``resume_run_id`` reopens an existing
    run (its name, params and config stay as first logged). ``reads``: the stage's declaration
    of what it reads; its digest of ``cfg`` is tagged ``armexp.inputs_hash``, by which
    ``pipeline.reuse`` finds the run (`armexp.reuse`).
    """
    experiment_id = setup(cfg)
    tags = {
        STAGE_TAG: stage,
        liveness.HEARTBEAT_TAG: f"{time.time():.0f}",
        liveness.PROCESS_TAG: liveness.process_identity(),
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
        run = retry(lambda: mlflow.start_run(run_id=resume_run_id, nested=bool(parent_run_id)))
        mlflow.set_tags({k: v for k, v in tags.items() if k != STAGE_TAG})
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


def log_folder(local_dir: str | Path, artifact_path: str | None = None) -> None:
    """Log every file under ``local_dir`` as artifacts under ``artifact_path``, one at a time in
    sorted order: each is written under a temporary name and renamed when complete (MLflow's
    ``log_artifacts`` copies a folder in place, so a failed write leaves a cut-off file)."""
    root = Path(local_dir)
    for path in sorted(p for p in root.rglob("*") if p.is_file()):
        parent = path.parent.relative_to(root).as_posix()
        folder = "/".join(x for x in (artifact_path, "" if parent == "." else parent) if x)
        retry(lambda p=path, f=folder: mlflow.log_artifact(str(p), f or None))  # type: ignore[misc]


def log_dataframe(df: Any, name: str, folder: str | None = None) -> None:
    """Log a pandas DataFrame as an artifact (under ``folder``); the suffix picks Parquet or CSV."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / name
        if name.endswith(".parquet"):
            df.to_parquet(path, index=False)
        else:
            df.to_csv(path, index=False)
        retry(lambda: mlflow.log_artifact(str(path), folder))


#: MLflow's limits on one batch call.
BATCH_METRICS, BATCH_PARAMS = 1000, 100


def log_batch(
    run_id: str,
    metrics: Sequence[Metric] = (),
    params: Mapping[str, str] | None = None,
    client: MlflowClient | None = None,
) -> None:
    """Log ``metrics`` and ``params`` to a run in as few calls as MLflow's batch limits allow,
    each retried while the store is busy (`retry`)."""
    client = client or MlflowClient()
    for i in range(0, len(metrics), BATCH_METRICS):
        chunk = list(metrics[i : i + BATCH_METRICS])
        retry(lambda c=chunk: client.log_batch(run_id, metrics=c))  # type: ignore[misc]
    items = [Param(k, str(v)) for k, v in sorted((params or {}).items())]
    for i in range(0, len(items), BATCH_PARAMS):
        chunk_p = items[i : i + BATCH_PARAMS]
        retry(lambda c=chunk_p: client.log_batch(run_id, params=c))  # type: ignore[misc]


def log_metric_history(name: str, values: Any, start_step: int = 0) -> None:
    """Log a whole series as one metric's history (batch calls, not one per point)."""
    now = int(time.time() * 1000)
    metrics = [Metric(name, float(v), now, start_step + i) for i, v in enumerate(values)]
    log_batch(mlflow.active_run().info.run_id, metrics)  # type: ignore[union-attr]


# ------------------------------------------------------------------------------------- lookup
def find_stage_run(
    cfg: DictConfig,
    stage: str,
    run_id: str | None = None,
    match: Mapping[str, str] | None = None,
    key: str = "run",
    statuses: tuple[str, ...] = ("FINISHED",),
    accept: Callable[[Run], bool] | None = None,
    wanted: str = "",
) -> Run:
    """The upstream run a stage consumes: ``run_id`` if given, else the latest FINISHED run of
    ``stage`` in the configured experiment whose params equal ``match`` (and, with ``accept``,
    for which ``accept(run)`` holds: a condition a search filter cannot say, such as a param that
    older runs lack; ``wanted`` describes it in the error). A given ``run_id`` is not held to
    ``match`` or ``accept``: the caller checks it and names what is wrong.

    Raises `ConfigError` with one sentence when the id does not exist, belongs to another stage,
    is not in one of ``statuses``, or when no run matches. ``key`` names the config key that
    carries the id.
    """
    experiment_id = setup(cfg)
    client = MlflowClient(store_uri(cfg))
    match = dict(match or {})
    if run_id:
        run_id = run_ids.resolve(client, str(run_id), key, store.hide_password(store_uri(cfg)))
        try:
            run = client.get_run(run_id)
        except MlflowException:
            raise ConfigError(
                f"{key}={run_id} is not allowed: no run with that id exists in the store "
                f"{store_uri(cfg)}."
            ) from None
        got = run.data.tags.get(STAGE_TAG)
        if got != stage:
            raise ConfigError(
                f"{key}={run_id} is not allowed: it is a {got or 'non-armexp'} run, and a "
                f"{stage} run is needed here."
            )
        if run.info.status not in statuses:
            raise ConfigError(
                f"{key}={run_id} is not allowed: that {stage} run is {run.info.status}, and only "
                f"{' or '.join(statuses)} runs can be used here."
            )
        return run
    clauses = [f"tags.`{STAGE_TAG}` = '{stage}'", "attributes.status = 'FINISHED'"]
    clauses += [f"params.`{k}` = '{v}'" for k, v in match.items()]
    found = _latest(client, experiment_id, " and ".join(clauses), accept)
    if found is None:
        what = ", ".join([*(f"{k}={v}" for k, v in match.items()), *([wanted] if wanted else [])])
        raise ConfigError(
            f"{key} is not set and no FINISHED {stage} run with {what or 'any config'} exists in "
            f"experiment '{cfg.tracking.experiment}' at {store_uri(cfg)}; run `armexp {stage}` "
            f"with those settings first or pass {key}=<run id>."
        )
    log.info("using %s run %s (latest matching %s)", stage, found.info.run_id, match)
    return found


def _latest(
    client: MlflowClient,
    experiment_id: str,
    filter_string: str,
    accept: Callable[[Run], bool] | None,
) -> Run | None:
    """The newest run that the filter selects and ``accept`` (if given) takes, page by page."""
    token = None
    while True:
        page = retry(
            lambda t=token: client.search_runs(  # type: ignore[misc]
                [experiment_id],
                filter_string=filter_string,
                order_by=["attributes.start_time DESC"],
                max_results=1 if accept is None else 100,
                page_token=t,
            )
        )
        for run in page:
            if accept is None or accept(run):
                return run
        token = page.token
        if accept is None or not token:
            return None


_download_root: Path | None = None


def _downloads() -> Path:
    """This process's folder for downloaded artifacts, removed when the process exits."""
    global _download_root
    if _download_root is None:
        _download_root = Path(tempfile.mkdtemp(prefix="armexp-"))
        atexit.register(shutil.rmtree, _download_root, True)
    return _download_root


def download_artifact(run_id: str, path: str, cfg: DictConfig) -> Path:
    """Fetch one artifact of a run into a temporary folder and return its local path."""
    mlflow.set_tracking_uri(store_uri(cfg))
    dst = tempfile.mkdtemp(dir=_downloads())
    return Path(
        mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=path, dst_path=dst)
    )
