"""What a stage run logs besides its params, and how a run's artifacts come back.

Folders and tables are logged file by file, each written under a temporary name and renamed when
complete (`armexp.disk`); a metric's whole series and many params go in MLflow's batch calls;
`download_artifact` fetches one artifact of a run into a folder removed when the process exits.
Every call is retried while a SQLite store is busy (`armexp.tracking.store.retry`).
"""

from __future__ import annotations

import atexit
import shutil
import tempfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import mlflow
from mlflow.entities import Metric, Param
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.tracking.store import retry, store_uri


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
