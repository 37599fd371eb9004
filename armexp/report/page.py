"""The report's tables, figures and ``index.html``, written into one folder from what
`armexp.report.gather` read."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import DictConfig

from armexp.report import claims, figures, gather, performance, seed_figures, summary, tables
from armexp.report.runs import TASKS, Reader, Selection

#: Above this many train runs the per-run training curves give way to the across-seed ones.
MAX_TRAINING_CURVES = 4


def build(selection: Selection, reader: Reader, folder: Path, cfg: DictConfig) -> dict[str, float]:
    """Every table and figure of the report into ``folder``; returns headline numbers."""
    primary = selection.evals[0]
    train_id = primary.data.tags.get(gather.TRAIN_RUN_TAG, "")
    configs = {tid: reader.yaml(tid, "config.yaml") for tid in sorted(selection.trains)}
    gather.check_one_setting(selection, configs)
    train_cfg = configs.get(train_id)
    agents = gather.agents_of(selection, configs)
    episodes = gather.episodes_of(selection, reader, agents)
    ctx = gather.context_of(selection, agents, train_cfg)
    ctx.missing = gather.missing_seeds(selection, [int(s) for s in cfg.report.seeds])

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
    tunes = gather.tunes_of(selection, reader)
    if tunes:
        made.append(tables.cso_table(tunes))
    for t in made:
        t.write(folder / "tables")

    pictures: list[tuple[str, str]] = []

    def save(fig: Any, name: str, caption: str) -> None:
        figures.save(fig, folder / "figures", name)
        pictures.append((name, caption))

    runs_frame = gather.runs_table(selection, agents)
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
    curves = gather.training_curves(selection, reader)
    if curves and len(curves) <= MAX_TRAINING_CURVES:
        save(
            figures.learning_curves(curves),
            "training_curves",
            "Training curves of each train run: success rate and episode reward against "
            "environment steps.",
        )
    groups = gather.held_out_curves(selection, reader, agents)
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
    animations = gather.animations_of(primary.info.run_id, reader, folder)
    index_page(folder, made, pictures, animations, runs_frame, selection, cfg, ctx.agent)
    return gather.headline(episodes)


def index_page(
    folder: Path,
    made: list[tables.Table],
    pictures: list[tuple[str, str]],
    animations: list[tuple[str, str, dict[str, str]]],
    runs_frame: pd.DataFrame,
    selection: Selection,
    cfg: DictConfig,
    agent: str,
) -> None:
    ids = ",".join(r.info.run_id for r in selection.evals)
    command = f"armexp report report.eval_runs=[{ids}] tracking.runs_dir={cfg.tracking.runs_dir}"
    if cfg.tracking.uri:
        command += f" tracking.uri={cfg.tracking.uri}"
    ui = ui_base(cfg)
    linked = runs_frame.assign(
        run_id=[
            f"<a href='{_run_link(ui, run)}'>{html.escape(run.info.run_id)}</a>"
            for run in _by_id(selection, list(runs_frame.run_id))
        ]
    )
    runs_html = linked.to_html(index=False, escape=False, border=0)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>armexp report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
        "table{border-collapse:collapse;margin:.5em 0}td,th{border-bottom:1px solid #ccc;"
        "padding:.2em .6em;text-align:left}img{max-width:100%}.note{color:#555;font-size:90%}"
        "code{background:#f4f4f4;padding:.1em .3em}"
        ".agent{border-left:4px solid #c60;padding:.2em .6em;background:#fff6ec}"
        ".animations{display:grid;grid-template-columns:repeat(2,1fr);gap:.5em}</style>"
        "</head><body>",
        "<h1>armexp report</h1>",
        *_glance(made[0] if made and made[0].name == "summary" else None, selection, cfg),
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
        *_animation_section(animations, selection.evals[0].info.run_id),
        "<h2>Runs used</h2>",
        runs_html,
        f"<p>Run ids link to the MLflow UI at <code>{html.escape(ui)}</code> (start it with "
        "<code>armexp ui</code>); each run's <code>config.yaml</code> artifact is its resolved "
        "config.</p>",
        "<h2>Regenerate</h2>",
        f"<pre>{html.escape(command)}</pre>",
        "</body></html>",
    ]
    (folder / "index.html").write_text("\n".join(parts))


def _animation_section(animations: list[tuple[str, str, dict[str, str]]], run_id: str) -> list[str]:
    """The paper tasks as the eval run animated them: the GIFs inline, task by task with the
    controllers side by side, each with a link to its MP4."""
    if not animations:
        return []
    names = {"adaptive": "proposed", "pid": "PID"}
    cells = []
    for label, task, files in sorted(animations, key=lambda a: (a[1], a[0])):
        caption = f"({task}), {names.get(label, label)}"
        video = f" (<a href='{files['mp4']}'>MP4</a>)" if "mp4" in files else ""
        cells.append(
            f"<figure><img src='{files['gif']}' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)}{video}</figcaption></figure>"
        )
    return [
        "<h2>Animations</h2>",
        f"<p>Tasks (a)–(d) as eval run <code>{html.escape(run_id)}</code> ran them, one frame per "
        "30 ms action: the arm, the obstacles, the target with its reach threshold, the tip's "
        "trace, and the time and joint torques (red at the torque limit).</p>",
        "<div class='animations'>",
        *cells,
        "</div>",
    ]


def ui_base(cfg: DictConfig) -> str:
    """Where the MLflow UI for this store is: the tracking server itself, or `armexp ui`'s
    address for a local store."""
    uri = str(cfg.tracking.uri or "")
    if uri.startswith(("http://", "https://")):
        return uri.rstrip("/")
    return f"http://{cfg.ui.host}:{cfg.ui.port}"


def _run_link(base: str, run: Any) -> str:
    return f"{base}/#/experiments/{run.info.experiment_id}/runs/{run.info.run_id}"


def _by_id(selection: Selection, ids: list[str]) -> list[Any]:
    runs = {r.info.run_id: r for r in selection.all_runs}
    return [runs[i] for i in ids]


def _glance(summary_table: tables.Table | None, selection: Selection, cfg: DictConfig) -> list[str]:
    """The page's opening: what ran (runs, seeds, agents, gains), held-out success and the
    claim check's verdicts per agent, with links to the eval runs in the MLflow UI."""
    ui = ui_base(cfg)
    seeds = sorted({r.data.params.get("seed", "?") for r in selection.evals}, key=str)
    links = ", ".join(
        f"<a href='{_run_link(ui, r)}'>{html.escape(r.info.run_id[:8])}</a>"
        for r in selection.evals
    )
    # An explicit list of eval runs is already the links; other selections say how they chose.
    how = "" if selection.how.startswith("eval runs ") else f" ({html.escape(selection.how)})"
    items = [
        f"<li>What ran: {len(selection.evals)} eval run(s) ({links}), seed(s) "
        f"{html.escape(', '.join(seeds))}{how}. Every number below was read from the MLflow "
        "store; nothing was re-simulated.</li>"
    ]
    tuned = sorted(
        ((r.data.params.get("controller.name", "?"), r) for r in selection.tunes.values()),
        key=lambda pair: (pair[0], pair[1].info.run_id),
    )
    if tuned:
        gains = ", ".join(
            f"{html.escape(name)} (<a href='{_run_link(ui, r)}'>{r.info.run_id[:8]}</a>)"
            for name, r in tuned
        )
        items.append(f"<li>Gains tuned by cuckoo search in: {gains}.</li>")
    if summary_table is not None:
        for row in summary_table.shown.to_dict("records"):
            items.append(
                f"<li><b>{html.escape(str(row['Agent']))}</b>: held-out success "
                f"{html.escape(str(row['Held-out success, proposed']))} with the proposed "
                f"control, {html.escape(str(row['Held-out success, PID']))} with PID; paper "
                f"tasks reached {html.escape(str(row['Paper tasks reached']))}; convergence claim "
                f"<i>{html.escape(str(row['verdict (≈ 10 %)']))}</i>, accuracy claim "
                f"<i>{html.escape(str(row['verdict (≈ 18 %)']))}</i>.</li>"
            )
    return ["<h2>At a glance</h2>", "<ul class='glance'>", *items, "</ul>"]
