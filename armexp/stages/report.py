"""`armexp report`: the paper's Tables I–III and Figures 3–6 from stored runs alone.

Selects eval runs (``report.eval_runs``, ``report.pipeline_run``, ``report.filter``, or by default
those of the latest pipeline run, else the latest eval run), follows their lineage tags to the
train and tune runs, reads everything through MLflow's API into pandas, and writes into
``report.out_dir`` (default ``<runs_dir>/report``): tables as Markdown, LaTeX and CSV, figures as
PNG and PDF, ``runs.csv`` and ``index.html``. The folder is then logged as the artifact
``report/`` of a report run. It never imports the simulation, environment or agent code.
"""

from __future__ import annotations

import html
import math
import shutil
from pathlib import Path
from typing import Any

import mlflow
import pandas as pd
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp import tracking
from armexp.report import figures, tables
from armexp.report.runs import CONTROLLERS, TASKS, Reader, Selection, select

REPORT_RUNS_TAG = "armexp.report_runs"


def out_dir(cfg: DictConfig) -> Path:
    folder = cfg.report.out_dir or str(Path(cfg.tracking.runs_dir) / "report")
    return Path(folder).resolve()


def run(cfg: DictConfig) -> dict[str, float]:
    uri = tracking.store_uri(cfg)
    client = MlflowClient(uri)
    selection = select(
        client,
        str(cfg.report.experiment or cfg.tracking.experiment),
        pipeline_run=cfg.report.pipeline_run,
        eval_runs=[str(r) for r in cfg.report.eval_runs],
        filter_string=cfg.report.filter,
    )
    folder = out_dir(cfg)
    if folder.exists():
        shutil.rmtree(folder)
    (folder / "figures").mkdir(parents=True)
    (folder / "tables").mkdir()
    summary = build(selection, Reader(uri), folder, cfg)
    ids = ",".join(r.info.run_id for r in selection.evals)
    with tracking.stage_run(
        cfg, "report", run_name=cfg.report.run_name, extra_tags={REPORT_RUNS_TAG: ids[:5000]}
    ) as active:
        mlflow.log_metrics({k: v for k, v in summary.items() if math.isfinite(v)})
        tracking.retry(lambda: mlflow.log_artifacts(str(folder), "report"))
        print(
            f"report: run {active.info.run_id} | {len(selection.evals)} eval run(s) "
            f"({selection.how}) | open {folder / 'index.html'}"
        )
    return summary


def build(selection: Selection, reader: Reader, folder: Path, cfg: DictConfig) -> dict[str, float]:
    """Every table and figure of the report into ``folder``; returns headline numbers."""
    episodes = _episodes(selection, reader)
    primary = selection.evals[0]
    train_id = primary.data.tags.get("armexp.train_run", "")
    train_cfg = reader.yaml(train_id, "config.yaml") if train_id else None

    made: list[tables.Table] = []
    if train_cfg:
        made += [tables.table_one(train_cfg), tables.table_two(train_cfg)]
    made += [tables.table_three(episodes), tables.comparison(episodes)]
    tunes = _tunes(selection, reader)
    if tunes:
        made.append(tables.cso_table(tunes))
    for t in made:
        t.write(folder / "tables")

    pictures: list[tuple[str, str]] = []

    def save(fig: Any, name: str, caption: str) -> None:
        figures.save(fig, folder / "figures", name)
        pictures.append((name, caption))

    runs_frame = _runs_table(selection)
    runs_frame.to_csv(folder / "runs.csv", index=False)
    trajectories = {
        task: frame
        for task in TASKS
        if (frame := reader.frame(primary.info.run_id, f"trajectories/adaptive/{task}.parquet"))
        is not None
    }
    first = episodes[episodes.eval_run == primary.info.run_id]
    targets = {
        str(r.task): (float(r.target_x), float(r.target_y))
        for r in first[first.controller == "adaptive"].itertuples()
        if r.task in TASKS
    }
    if trajectories and train_cfg:
        env, robot = train_cfg["env"], train_cfg["robot"]
        save(
            figures.tip_paths(
                trajectories,
                targets,
                train_cfg["obstacles"]["circles"],
                robot["lengths"],
                robot["q0"],
                env["reach_threshold"],
            ),
            "fig3_tip_paths",
            "Fig. 3: tip paths of tasks (a)–(d) around the obstacles.",
        )
        save(
            figures.target_error(trajectories, env["reach_threshold"]),
            "fig4_target_error",
            "Fig. 4: tip-to-target error against time.",
        )
        save(figures.torques(trajectories), "fig5_torques", "Fig. 5: joint torques.")
        task = str(cfg.report.fig6_task)
        if task in trajectories:
            save(
                figures.tracking(trajectories[task], task),
                "fig6_tracking",
                f"Fig. 6: joint position tracking in task ({task}), first 0.1 s enlarged.",
            )
    curves = _learning_curves(selection, reader)
    if curves:
        save(
            figures.learning_curves(curves),
            "learning_curves",
            "Learning curves: success rate and episode reward against environment steps.",
        )
    if tunes:
        histories = {f"{t['controller']} ({t['run_id'][:8]})": t["history"] for t in tunes}
        paper = {
            f"{t['controller']} ({t['run_id'][:8]})": t["paper_objective"]
            for t in tunes
            if t["controller"] != "pid"
        }
        save(
            figures.cso_convergence(histories, paper),
            "cso_convergence",
            "Cuckoo search: best objective per iteration.",
        )
    _index(folder, made, pictures, runs_frame, selection, cfg)
    return _headline(episodes)


def _episodes(selection: Selection, reader: Reader) -> pd.DataFrame:
    frames = []
    for ev in selection.evals:
        frame = reader.frame(ev.info.run_id, "episodes.csv")
        if frame is None:
            continue
        frame.insert(0, "eval_run", ev.info.run_id)
        frame.insert(1, "seed", ev.data.params.get("seed", ""))
        frames.append(frame)
    if not frames:
        from armexp.config import ConfigError

        raise ConfigError(
            "the report has nothing to show: the selected eval runs have no episodes.csv "
            "artifact (were their artifacts deleted?)."
        )
    return pd.concat(frames, ignore_index=True)


def _tunes(selection: Selection, reader: Reader) -> list[dict[str, Any]]:
    out = []
    for run_id, run in sorted(selection.tunes.items()):
        m = run.data.metrics
        out.append(
            {
                "run_id": run_id,
                "controller": "pid"
                if run.data.params.get("controller.name") == "pid"
                else "adaptive",
                "gains": reader.yaml(run_id, "gains.yaml"),
                "best": m.get("best_objective", math.nan),
                "paper_objective": m.get("objective_paper_gains", math.nan),
                "history": reader.history(run_id, "best_objective"),
            }
        )
    return sorted(out, key=lambda t: (CONTROLLERS.index(t["controller"]), t["run_id"]))


def _learning_curves(selection: Selection, reader: Reader) -> dict[str, dict[str, pd.DataFrame]]:
    curves = {}
    for run_id, run in sorted(selection.trains.items()):
        label = f"seed {run.data.params.get('seed', '?')} ({run_id[:8]})"
        curves[label] = {
            "success": reader.history(run_id, "rollout/success_rate_100"),
            "reward": reader.history(run_id, "episode/reward"),
            "held_out": reader.history(run_id, "eval/success_rate"),
        }
    return curves


def _runs_table(selection: Selection) -> pd.DataFrame:
    rows = []
    for run in selection.all_runs:
        p = run.data.params
        rows.append(
            {
                "run_id": run.info.run_id,
                "stage": run.data.tags.get("armexp.stage", ""),
                "status": run.info.status,
                "seed": p.get("seed", ""),
                "controller": p.get("controller.name", ""),
                "robot": p.get("robot.name", ""),
                "obstacles": p.get("obstacles.name", ""),
                "agent": p.get("agent.name", ""),
                "git_commit": run.data.tags.get("armexp.git_commit", "")[:10],
            }
        )
    return pd.DataFrame(rows).drop_duplicates("run_id")


def _headline(episodes: pd.DataFrame) -> dict[str, float]:
    out: dict[str, float] = {"eval_runs": float(episodes.eval_run.nunique())}
    for label, rows in episodes.groupby("controller"):
        tasks = rows[rows.task.isin(list(TASKS))]
        rand = rows[rows.task.str.startswith("random_")]
        out[f"{label}.tasks.success_rate"] = float(tasks.success.mean()) if len(tasks) else math.nan
        out[f"{label}.random.success_rate"] = float(rand.success.mean()) if len(rand) else math.nan
    return out


def _index(
    folder: Path,
    made: list[tables.Table],
    pictures: list[tuple[str, str]],
    runs_frame: pd.DataFrame,
    selection: Selection,
    cfg: DictConfig,
) -> None:
    ids = ",".join(r.info.run_id for r in selection.evals)
    command = f"armexp report report.eval_runs=[{ids}] tracking.runs_dir={cfg.tracking.runs_dir}"
    if cfg.tracking.uri:
        command += f" tracking.uri={cfg.tracking.uri}"
    runs_html = runs_frame.to_html(index=False, escape=True, border=0)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>armexp report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:.5em 0}td,th{border-bottom:1px solid #ccc;"
        "padding:.2em .6em;text-align:left}img{max-width:100%}.note{color:#555;font-size:90%}"
        "code{background:#f4f4f4;padding:.1em .3em}</style></head><body>",
        "<h1>armexp report</h1>",
        f"<p>Made from {len(selection.evals)} eval run(s): {html.escape(selection.how)}. "
        "Every number below was read from the MLflow store; nothing was re-simulated.</p>",
        "<h2>Tables</h2>",
        "<p>Each table is also in <code>tables/</code> as Markdown, LaTeX (booktabs) and CSV.</p>",
        *(t.html() for t in made),
        "<h2>Figures</h2>",
        *(
            f"<figure><img src='figures/{name}.png' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)} (<a href='figures/{name}.pdf'>PDF</a>)"
            "</figcaption></figure>"
            for name, caption in pictures
        ),
        "<h2>Runs used</h2>",
        runs_html,
        "<p>Configs: each run's <code>config.yaml</code> artifact in the MLflow UI "
        "(<code>armexp ui</code>).</p>",
        "<h2>Regenerate</h2>",
        f"<pre>{html.escape(command)}</pre>",
        "</body></html>",
    ]
    (folder / "index.html").write_text("\n".join(parts))
