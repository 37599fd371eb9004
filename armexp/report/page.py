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
    runs_html = runs_frame.to_html(index=False, escape=True, border=0)
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
        *_animation_section(animations, selection.evals[0].info.run_id),
        "<h2>Runs used</h2>",
        runs_html,
        "<p>Configs: each run's <code>config.yaml</code> artifact in the MLflow UI "
        "(<code>armexp ui</code>).</p>",
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
