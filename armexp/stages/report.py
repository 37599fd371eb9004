"""`armexp report`: the paper's Tables I–III and Figures 3–6 from stored runs alone.

Selects eval runs (``report.eval_runs``, ``report.pipeline_run``, ``report.filter``, or by default
those of the latest pipeline run, else the latest eval run), follows their lineage tags to the
train and tune runs, reads everything through MLflow's API into pandas, and writes into
``report.out_dir`` (default ``<runs_dir>/report``): tables as Markdown, LaTeX and CSV, figures as
PNG and PDF, ``runs.csv`` and ``index.html``. The folder is then logged as the artifact
``report/`` of a report run. It never imports the simulation, environment or agent code.

Each eval run's agent (preset, learning aids, budget spent) comes from its train run
(`armexp.report.agent`); the eval run's own ``agent.*`` params are its stage defaults, not the
policy's. Its ``<controller>.<task>.<metric>`` metrics override ``episodes.csv`` for the paper
tasks; ``eval.initial_offset`` and ``robot.torque_limit`` params go into the footnotes.
"""

from __future__ import annotations

import html
import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

import mlflow
import pandas as pd
import yaml
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp import tracking
from armexp.config import ConfigError
from armexp.report import claims, figures, performance, seed_figures, summary, tables
from armexp.report.agent import PRESET_TAG, AgentInfo, agent_info, caption
from armexp.report.runs import CONTROLLERS, TASKS, Reader, Selection, metric_value, select

REPORT_RUNS_TAG = "armexp.report_runs"
#: The file that marks a folder as an armexp report (which a new report may replace).
MARKER = ".armexp-report"
GAINS_TAG = "armexp.adaptive_gains"
#: Above this many train runs the per-run training curves give way to the across-seed ones.
MAX_TRAINING_CURVES = 4
TRAIN_RUN_TAG = "armexp.train_run"


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
        tracking.retry(lambda: mlflow.log_artifacts(str(folder), "report"))
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


def build(selection: Selection, reader: Reader, folder: Path, cfg: DictConfig) -> dict[str, float]:
    """Every table and figure of the report into ``folder``; returns headline numbers."""
    primary = selection.evals[0]
    train_id = primary.data.tags.get(TRAIN_RUN_TAG, "")
    configs = {tid: reader.yaml(tid, "config.yaml") for tid in sorted(selection.trains)}
    _one_setting(selection, configs)
    train_cfg = configs.get(train_id)
    agents = _agents(selection, configs)
    episodes = _episodes(selection, reader, agents)
    ctx = _context(selection, agents, train_cfg)
    ctx.missing = _missing(selection, [int(s) for s in cfg.report.seeds])

    made: list[tables.Table] = []
    if train_cfg:
        trains = sorted(
            {a.train_run: a for a in agents.values() if a.known}.values(),
            key=lambda a: a.train_run != train_id,
        )
        made += [tables.table_one(train_cfg), tables.table_two(train_cfg, trains)]
    claim_table = claims.claim_check(episodes, ctx)
    made.insert(0, summary.summary(episodes, claim_table, ctx))
    made += [
        performance.table_three(episodes, ctx),
        performance.comparison(episodes, ctx),
        claim_table,
    ]
    tunes = _tunes(selection, reader)
    if tunes:
        made.append(tables.cso_table(tunes))
    for t in made:
        t.write(folder / "tables")

    pictures: list[tuple[str, str]] = []

    def save(fig: Any, name: str, caption: str) -> None:
        figures.save(fig, folder / "figures", name)
        pictures.append((name, caption))

    runs_frame = _runs_table(selection, agents)
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
    if curves and len(curves) <= MAX_TRAINING_CURVES:
        save(
            figures.learning_curves(curves),
            "training_curves",
            "Training curves of each train run: success rate and episode reward against "
            "environment steps.",
        )
    groups = _held_out_curves(selection, reader, agents)
    if groups:
        save(
            seed_figures.learning_curves_ci(groups, n_boot=performance.N_BOOT),
            "learning_curves",
            "Learning curves: held-out success of the policy as it trained, IQM across seeds "
            "with a 95 % stratified bootstrap band, per agent preset.",
        )
    short = performance.agent_names(episodes)
    named = episodes.assign(agent=episodes.agent.map(short)) if short else episodes
    profiles = seed_figures.performance_profiles(named, n_boot=performance.N_BOOT)
    if profiles is not None:
        save(
            profiles,
            "performance_profiles",
            "Performance profiles on the held-out targets, both controllers: the share of runs "
            "above each success rate and of episodes below each tip tracking error, with 95 % "
            "stratified bootstrap bands across seeds.",
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
    _index(folder, made, pictures, runs_frame, selection, cfg, ctx.agent)
    return _headline(episodes)


def _agents(selection: Selection, configs: dict[str, Any]) -> dict[str, AgentInfo]:
    """The agent behind each eval run (by eval run id), from its train run."""
    out = {}
    for ev in selection.evals:
        tid = ev.data.tags.get(TRAIN_RUN_TAG, "")
        info = agent_info(tid, selection.trains.get(tid), configs.get(tid))
        if ev.data.tags.get(GAINS_TAG) == "config":
            info.gains = _gains_label(ev)
        out[ev.info.run_id] = info
    return out


def _gains_label(ev: Any) -> str:
    """How an eval run with ``eval.adaptive_gains=config`` is named: "paper gains" when its
    logged ``controller.gains.*`` are the paper's."""
    published = tables.paper_gains()
    logged = {k: _param(ev.data.params.get(f"controller.gains.{k}")) for k in published}
    same = all(
        isinstance(v, int | float) and math.isclose(float(v), published[k])
        for k, v in logged.items()
    )
    return "paper gains" if same else "configured gains"


def _one_setting(selection: Selection, configs: dict[str, Any]) -> None:
    """One robot and one obstacle set: the tables compare episodes task by task."""
    for key in ("robot", "obstacles"):
        seen: dict[str, str] = {}
        for ev in selection.evals:
            tid = ev.data.tags.get(TRAIN_RUN_TAG, "")
            cfg = configs.get(tid) or {}
            name = (cfg.get(key) or {}).get("name") or ev.data.params.get(f"{key}.name")
            if name is not None:
                seen.setdefault(str(name), ev.info.run_id)
        if len(seen) > 1:
            runs = ", ".join(f"{name} (eval run {rid})" for name, rid in seen.items())
            raise ConfigError(
                f"report.eval_runs mixes {key} settings, which is not allowed: {runs}; select "
                f"eval runs of one {key} setting per report."
            )


def _missing(selection: Selection, seeds: list[int]) -> str | None:
    """The sentence naming the expected seeds without a selected eval run (None: none)."""
    have = set()
    for ev in selection.evals:
        try:
            have.add(int(ev.data.params.get("seed", "")))
        except ValueError:
            continue
    missing = [s for s in seeds if s not in have]
    if not missing:
        return None
    listed = ", ".join(map(str, missing))
    return (
        f"Missing: seed{'s' if len(missing) > 1 else ''} {listed} of {len(seeds)} has no finished "
        f"eval run (its pipeline failed or was interrupted); the statistics are over the other "
        f"{len(seeds) - len(missing)}."
    )


def _param(text: str | None) -> Any:
    """A logged param as a value (None for a missing or null one)."""
    if text is None:
        return None
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    return None if value in ("None", "") else value


def _episodes(selection: Selection, reader: Reader, agents: dict[str, AgentInfo]) -> pd.DataFrame:
    """Every episode of the selected eval runs (``episodes.csv``), with the agent that ran it,
    and the eval run's ``<controller>.<task>.<metric>`` metrics over the paper tasks' rows
    (the same numbers where both exist; a metric ±inf, stored as ±float max, reads as ±inf)."""
    frames = []
    for ev in selection.evals:
        frame = reader.frame(ev.info.run_id, "episodes.csv")
        if frame is None:
            continue
        run_id = ev.info.run_id
        frame.insert(0, "eval_run", run_id)
        frame.insert(1, "seed", ev.data.params.get("seed", ""))
        info = agents[run_id]
        frame.insert(2, "agent", info.label)
        frame.insert(3, "agent_preset", info.preset)
        frame.insert(4, "aided", info.aided)
        frame.insert(5, "gains", info.gains)
        paper = frame.task.isin(list(TASKS))
        for name, value in sorted(ev.data.metrics.items()):
            label, _, rest = name.partition(".")
            task, _, key = rest.partition(".")
            if label in CONTROLLERS and task in TASKS and key and "." not in key:
                rows = paper & (frame.controller == label) & (frame.task == task)
                if rows.any():
                    frame.loc[rows, key] = metric_value(value)
        frames.append(frame)
    if not frames:
        raise ConfigError(
            "the report has nothing to show: the selected eval runs have no episodes.csv "
            "artifact (were their artifacts deleted?)."
        )
    return pd.concat(frames, ignore_index=True)


def _values(texts: list[str | None], show: Any) -> str | None:
    """One logged param over the eval runs, shown; None when no run logs it."""
    shown = list(dict.fromkeys(show(v) for v in map(_param, texts) if v is not None))
    if not shown:
        return None
    return shown[0] if len(shown) == 1 else " / ".join(shown) + " (differs between runs)"


def _per_joint(value: Any, unit: str, sign: str = "") -> str:
    values = value if isinstance(value, list) else [value]
    return ", ".join(f"{sign}{float(v):g}" for v in values) + f" {unit}"


def _context(
    selection: Selection, agents: dict[str, AgentInfo], train_cfg: dict[str, Any] | None
) -> tables.Context:
    """What Tables III and the PID comparison say beside their numbers."""
    infos = list({a.label: a for a in agents.values()}.values())
    counts = [sum(a.label == i.label for a in agents.values()) for i in infos]
    params = [ev.data.params for ev in selection.evals]
    limit = _values(
        [p.get("robot.torque_limit") for p in params], lambda v: _per_joint(v, "N·m", "±")
    )
    if limit is None and train_cfg and train_cfg.get("robot", {}).get("torque_limit"):
        limit = _per_joint(train_cfg["robot"]["torque_limit"], "N·m", "±")
    threshold = (train_cfg or {}).get("env", {}).get("reach_threshold", 0.04)
    return tables.Context(
        agent=caption(infos, counts),
        initial_offset=_values(
            [p.get("eval.initial_offset") for p in params], lambda v: _per_joint(v, "rad")
        ),
        torque_limit=limit,
        reach_threshold=float(threshold),
        plain_missing=any(a.aided for a in infos)
        and not any(a.known and not a.aids for a in infos),
    )


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
        preset = run.data.tags.get(PRESET_TAG) or run.data.params.get("agent.name", "?")
        label = f"{preset}, seed {run.data.params.get('seed', '?')} ({run_id[:8]})"
        curves[label] = {
            "success": reader.history(run_id, "rollout/success_rate_100"),
            "reward": reader.history(run_id, "episode/reward"),
            "held_out": reader.history(run_id, "eval/success_rate"),
        }
    return curves


def _held_out_curves(
    selection: Selection, reader: Reader, agents: dict[str, AgentInfo]
) -> dict[str, list[pd.DataFrame]]:
    """Held-out success histories (``eval/success_rate``) per agent preset, one per train run."""
    by_train = {a.train_run: a for a in agents.values()}
    groups: dict[str, list[pd.DataFrame]] = {}
    for run_id in sorted(selection.trains):
        history = reader.history(run_id, "eval/success_rate")
        info = by_train.get(run_id)
        if not len(history) or info is None:
            continue
        label = f"{info.preset} ({'aided' if info.aided else 'plain'})"
        groups.setdefault(label, []).append(history)
    return groups


def _runs_table(selection: Selection, agents: dict[str, AgentInfo]) -> pd.DataFrame:
    """One row per run used; ``agent`` is the train run's preset (an eval run's own
    ``agent.*`` params are its stage defaults, not the policy's)."""
    by_train = {a.train_run: a for a in agents.values()}
    rows = []
    for run in selection.all_runs:
        p = run.data.params
        stage = run.data.tags.get("armexp.stage", "")
        info = agents.get(run.info.run_id) if stage == "eval" else by_train.get(run.info.run_id)
        rows.append(
            {
                "run_id": run.info.run_id,
                "stage": stage,
                "status": run.info.status,
                "seed": p.get("seed", ""),
                "controller": p.get("controller.name", ""),
                "robot": p.get("robot.name", ""),
                "obstacles": p.get("obstacles.name", ""),
                "agent": info.preset if info else "",
                "aided": ("yes" if info.aided else "no") if info and info.known else "",
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
    agent: str,
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
        "code{background:#f4f4f4;padding:.1em .3em}"
        ".agent{border-left:4px solid #c60;padding:.2em .6em;background:#fff6ec}</style>"
        "</head><body>",
        "<h1>armexp report</h1>",
        f"<p>Made from {len(selection.evals)} eval run(s): {html.escape(selection.how)}. "
        "Every number below was read from the MLflow store; nothing was re-simulated.</p>",
        f"<p class='agent'>{html.escape(agent)}</p>",
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
