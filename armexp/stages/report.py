"""`armexp report`: the paper's Tables I–III and Figures 3–6 from stored runs alone.

Selects eval runs (``report.eval_runs``, ``report.pipeline_run``, ``report.filter``, or by default
those of the latest pipeline run, else the latest eval run), follows their lineage tags to the
train and tune runs, reads everything through MLflow's API into pandas, and writes into
``report.out_dir`` (default ``<runs_dir>/report``): tables as Markdown, LaTeX and CSV, figures as
PNG and PDF, ``runs.csv`` and ``index.html``. The folder is then logged as the artifact
``report/`` of a report run (`armexp.report.gather` reads, `armexp.report.page` writes). It
never imports the simulation, environment or agent code.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path

import mlflow
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp import tracking
from armexp.config import ConfigError
from armexp.report.page import build
from armexp.report.runs import Reader, select

REPORT_RUNS_TAG = "armexp.report_runs"
#: The file that marks a folder as an armexp report (which a new report may replace).
MARKER = ".armexp-report"


def out_dir(cfg: DictConfig) -> Path:
    folder = cfg.report.out_dir or str(Path(cfg.tracking.runs_dir) / "report")
    return Path(folder).resolve()


def run(cfg: DictConfig) -> tracking.StageResult:
    uri = tracking.store_uri(cfg)
    client = MlflowClient(uri)
    selection = select(
        client,
        str(cfg.report.experiment or cfg.tracking.experiment),
        pipeline_run=cfg.report.pipeline_run,
        eval_runs=[str(r) for r in cfg.report.eval_runs],
        filter_string=cfg.report.filter,
    )
    target = out_dir(cfg)
    _check_out_dir(target)
    # Built beside the target and swapped in when complete: an interrupted or failed report
    # leaves the previous one as it was.
    target.parent.mkdir(parents=True, exist_ok=True)
    folder = Path(tempfile.mkdtemp(prefix=f".{target.name}.", dir=target.parent))
    reader = Reader(uri)
    try:
        (folder / "figures").mkdir()
        (folder / "tables").mkdir()
        (folder / MARKER).write_text("made by armexp report; the folder is replaced as a whole\n")
        summary = build(selection, reader, folder, cfg)
        _swap(folder, target)
    finally:
        reader.close()
        shutil.rmtree(folder, ignore_errors=True)
    folder = target
    ids = ",".join(r.info.run_id for r in selection.evals)
    with tracking.stage_run(
        cfg, "report", run_name=cfg.report.run_name, extra_tags={REPORT_RUNS_TAG: ids[:5000]}
    ) as active:
        mlflow.log_metrics({k: v for k, v in summary.items() if math.isfinite(v)})
        tracking.log_folder(folder, "report")
        print(
            f"report: run {active.info.run_id} | {len(selection.evals)} eval run(s) "
            f"({selection.how}) | open {folder / 'index.html'}"
        )
    return tracking.StageResult(active.info.run_id, summary)


def _check_out_dir(folder: Path) -> None:
    """A report replaces its folder as a whole, so it writes only into a new or empty folder or
    into a previous report's (one holding the `MARKER` file)."""
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"report.out_dir={folder} is not allowed: it is a file, not a folder.")
    # Reports made before the marker existed are recognised by their layout.
    earlier = (folder / MARKER).exists() or (
        (folder / "index.html").is_file() and (folder / "tables").is_dir()
    )
    if folder.is_dir() and any(folder.iterdir()) and not earlier:
        raise ConfigError(
            f"report.out_dir={folder} is not allowed: the folder holds files that are not an "
            f"armexp report (no {MARKER} in it) and a report replaces its whole folder; give a "
            "new or empty folder, or an earlier report's."
        )


def _swap(new: Path, target: Path) -> None:
    """Put the finished report ``new`` where ``target`` is, removing the previous report."""
    old = None
    if target.exists():
        old = target.with_name(f".{target.name}.old-{os.getpid()}")
        target.rename(old)
    new.rename(target)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)
