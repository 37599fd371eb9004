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
from pathlib import Path

import mlflow
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.report import figures, folder, hpo
from armexp.report.folder import MARKER
from armexp.report.page import build
from armexp.report.runs import Reader, select
from armexp.tracking import artifacts, stage_runs, store
from armexp.tracking.tags import REPORT_RUNS_TAG

__all__ = ["MARKER", "REPORT_RUNS_TAG", "out_dir", "run"]


def out_dir(cfg: DictConfig) -> Path:
    """``report.out_dir``, by default ``<tracking.runs_dir>/report``."""
    return Path(cfg.report.out_dir or Path(cfg.tracking.runs_dir) / "report").resolve()


def run(cfg: DictConfig) -> stage_runs.StageResult:
    uri = store.store_uri(cfg)
    chosen = cfg.report.eval_runs or cfg.report.pipeline_run or cfg.report.filter
    if cfg.report.hpo_runs and not chosen:
        # Named HPOs with no eval selection: the report of those, not beside whichever eval
        # run the store happens to hold last.
        return _hpo_only(cfg, uri)
    selection = select(
        MlflowClient(uri),
        str(cfg.report.experiment or cfg.tracking.experiment),
        pipeline_run=cfg.report.pipeline_run,
        eval_runs=[str(r) for r in cfg.report.eval_runs],
        filter_string=cfg.report.filter,
        store=store.hide_password(uri),
    )
    target = out_dir(cfg)
    folder.check(target)
    # Built beside the target and swapped in when complete: an interrupted or failed report
    # leaves the previous one as it was.
    reader = Reader(uri)
    try:
        with folder.building(target) as new:
            (new / "figures").mkdir()
            (new / "tables").mkdir()
            summary = build(selection, reader, new, cfg)
    finally:
        reader.close()
    ids = ",".join(r.info.run_id for r in selection.evals)
    with stage_runs.stage_run(
        cfg, "report", run_name=cfg.report.run_name, extra_tags={REPORT_RUNS_TAG: ids[:5000]}
    ) as active:
        mlflow.log_metrics({k: v for k, v in summary.items() if math.isfinite(v)})
        artifacts.log_folder(target, "report")
        print(
            f"report: run {active.info.run_id} | {len(selection.evals)} eval run(s) "
            f"({selection.how}) | open {target / 'index.html'}"
        )
    return stage_runs.StageResult(active.info.run_id, summary)


def _hpo_only(cfg: DictConfig, uri: str) -> stage_runs.StageResult:
    """A report of ``report.hpo_runs`` alone (no eval run selection given)."""
    target = out_dir(cfg)
    folder.check(target)
    reader = Reader(uri)
    pictures: list[tuple[str, str]] = []
    try:
        with folder.building(target) as new:
            (new / "figures").mkdir()
            (new / "tables").mkdir()

            def save(fig: object, name: str, caption: str) -> None:
                figures.save(fig, new / "figures", name)
                pictures.append((name, caption))

            made = hpo.section(reader, [str(r) for r in cfg.report.hpo_runs], new, save)
            hpo.page(new, made, pictures)
    finally:
        reader.close()
    ids = ",".join(str(r) for r in cfg.report.hpo_runs)
    with stage_runs.stage_run(
        cfg, "report", run_name=cfg.report.run_name, extra_tags={REPORT_RUNS_TAG: ids[:5000]}
    ) as active:
        artifacts.log_folder(target, "report")
        print(
            f"report: run {active.info.run_id} | {len(cfg.report.hpo_runs)} HPO run(s), no eval "
            f"runs | open {target / 'index.html'}"
        )
    return stage_runs.StageResult(active.info.run_id, {})
