"""The report's tables, figures and ``index.html``, written into one folder from what
`armexp.report.gather` read."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import DictConfig

from armexp.report import (
    claims,
    comparison,
    figures,
    gather,
    hpo,
    labels,
    performance,
    seed_figures,
    summary,
    tables,
    tuning,
)
from armexp.report.agent import AgentInfo
from armexp.report.runs import TASKS, TRAIN_RUN_TAG, Reader, Selection

#: Above this many train runs the per-run training curves give way to the across-seed ones.
MAX_TRAINING_CURVES = 4


def build(selection: Selection, reader: Reader, folder: Path, cfg: DictConfig) -> dict[str, float]:
    """Every table and figure of the report into ``folder``; returns headline numbers."""
    primary = selection.evals[0]
    train_id = primary.data.tags.get(TRAIN_RUN_TAG, "")
    configs = {tid: reader.yaml(tid, "config.yaml") for tid in sorted(selection.trains)}
    gather.check_one_setting(selection, configs)
    train_cfg = configs.get(train_id)
    agents = gather.agents_of(selection, configs)
    run_labels = gather.labels_of(selection, reader)
    episodes = gather.episodes_of(selection, reader, agents, run_labels)
    ctx = gather.context_of(selection, agents, train_cfg)
    ctx.missing = gather.missing_seeds(selection, [int(s) for s in cfg.report.seeds])
    tunes = tuning.tunes_of(selection, reader, run_labels)
    made = _tables(episodes, ctx, train_cfg, agents, train_id, tunes)
    for t in made:
        t.write(folder / "tables")

    pictures: list[tuple[str, str]] = []

    def save(fig: Any, name: str, caption: str) -> None:
        figures.save(fig, folder / "figures", name)
        pictures.append((name, caption))

    made += hpo.section(reader, [str(r) for r in cfg.report.hpo_runs], folder, save)
    runs_frame = gather.runs_table(selection, agents)
    runs_frame.to_csv(folder / "runs.csv", index=False)
    shown = _figure_run(selection, run_labels)
    _paper_figures(shown, episodes, reader, train_cfg, str(cfg.report.fig6_task), save)
    _run_figures(selection, reader, agents, episodes, save)
    ids = {lab.tune_run for lab in run_labels[shown].values() if lab.tune_run}
    drawn = [t for t in tunes if t["run_id"] in ids] or tunes
    if drawn:
        histories = {_tune_name(t): t["history"] for t in drawn}
        paper = {
            _tune_name(t): t["paper_objective"] for t in drawn if t["controller"] == tuning.ADAPTIVE
        }
        which = f"eval run {shown[:8]}'s" if len(drawn) < len(tunes) else "every"
        save(
            figures.cso_convergence(histories, paper),
            "cso_convergence",
            f"Cuckoo search: best objective per iteration of {which} tune run (the tuning "
            "spread table covers every seed).",
        )
    animations = gather.animations_of(shown, run_labels[shown], reader, folder)
    index_page(folder, made, pictures, animations, runs_frame, selection, cfg, ctx.agent)
    return gather.headline(episodes)


def _tables(
    episodes: pd.DataFrame,
    ctx: tables.Context,
    train_cfg: dict[str, Any] | None,
    agents: dict[str, AgentInfo],
    train_id: str,
    tunes: list[dict[str, Any]],
) -> list[tables.Table]:
    """The report's tables, the summary first; the ablation, tuning and CSO tables only where
    the selection has something to put in them."""
    made: list[tables.Table] = []
    if train_cfg:
        trains = sorted(
            {a.train_run: a for a in agents.values() if a.known}.values(),
            key=lambda a: a.train_run != train_id,
        )
        made += [tables.table_one(train_cfg), tables.table_two(train_cfg, trains)]
    claim_table = claims.claim_check(episodes, ctx)
    ablation = comparison.ablation(episodes, ctx)
    made.insert(0, summary.summary(episodes, claim_table, ablation, ctx))
    made += [performance.table_three(episodes, ctx), comparison.comparison(episodes, ctx)]
    if len(ablation.shown):
        made.append(ablation)
    made.append(claim_table)
    if tunes:
        made += [tuning.spread_table(tunes), tuning.cso_table(tunes)]
    return made


def _tune_name(tune: dict[str, Any]) -> str:
    used = ", ".join(tune["labels"]) or tune["controller"]
    return f"{used} ({tune['criterion']}, {tune['run_id'][:8]})"


def _figure_run(selection: Selection, run_labels: dict[str, dict[str, labels.Label]]) -> str:
    """The eval run whose trajectories and animations the report shows: the first selected one
    that ran a baseline, else the first."""
    for ev in selection.evals:
        if any(lab.role == "baseline" for lab in run_labels.get(ev.info.run_id, {}).values()):
            return str(ev.info.run_id)
    return str(selection.evals[0].info.run_id)


def _paper_figures(
    run_id: str,
    episodes: pd.DataFrame,
    reader: Reader,
    train_cfg: dict[str, Any] | None,
    fig6_task: str,
    save: Any,
) -> None:
    """Figs. 3–6 from one eval run's trajectories: 3 and 4 of the proposed control, 5 of the
    proposed control and each baseline, 6 of the proposed control and its main baseline (the
    one compared with it; more panels than two per joint stop being readable)."""
    first = episodes[episodes.eval_run == run_id]
    proposed = performance.proposed_labels(first)
    if not proposed or not train_cfg:
        return
    ours = proposed[0]
    pairs = labels.comparisons(first)
    baselines = [b for b, _ in pairs]
    main = next((b for b, p in pairs if p == ours), baselines[0] if baselines else None)

    def load(label: str) -> dict[str, pd.DataFrame]:
        stored = str(first[first.controller == label].stored_label.iloc[0])
        return {
            task: frame
            for task in TASKS
            if (frame := reader.frame(run_id, f"trajectories/{stored}/{task}.parquet")) is not None
        }

    trajectories = {label: load(label) for label in [ours, *baselines]}
    own = trajectories[ours]
    if not own:
        return
    rows = first[(first.controller == ours) & first.task.isin(TASKS)]
    xs, ys = rows.target_x.astype(float), rows.target_y.astype(float)
    targets = {str(t): (float(x), float(y)) for t, x, y in zip(rows.task, xs, ys, strict=True)}
    env, robot = train_cfg["env"], train_cfg["robot"]
    where = f"eval run {run_id[:8]}"
    save(
        figures.tip_paths(own, targets, train_cfg["obstacles"]["circles"], robot["lengths"],
                          robot["q0"], env["reach_threshold"]),
        "fig3_tip_paths",
        f"Fig. 3: tip paths of tasks (a)–(d) around the obstacles ({ours}, {where}).",
    )  # fmt: skip
    save(
        figures.target_error(own, env["reach_threshold"]),
        "fig4_target_error",
        f"Fig. 4: tip-to-target error against time ({ours}, {where}).",
    )
    drawn = {label: frames for label, frames in trajectories.items() if frames}
    save(
        figures.torques(drawn),
        "fig5_torques",
        f"Fig. 5: joint torques of the proposed control and each baseline ({', '.join(drawn)}; "
        f"{where}).",
    )
    shown = {ours: own[fig6_task]} if fig6_task in own else {}
    if shown and main and fig6_task in trajectories.get(main, {}):
        shown[main] = trajectories[main][fig6_task]
    if shown:
        save(
            figures.tracking(shown, fig6_task),
            "fig6_tracking",
            f"Fig. 6: joint position tracking in task ({fig6_task}), first 0.1 s enlarged: the "
            f"proposed control and its main baseline ({' and '.join(shown)}; {where}).",
        )


def _run_figures(
    selection: Selection,
    reader: Reader,
    agents: dict[str, AgentInfo],
    episodes: pd.DataFrame,
    save: Any,
) -> None:
    """Training curves, learning curves across seeds and performance profiles."""
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
            "Performance profiles on the held-out targets, every controller label: the share of "
            "runs above each success rate and of episodes below each tip tracking error, with "
            "95 % stratified bootstrap bands across seeds.",
        )


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
    cells = []
    for label, task, files in sorted(animations, key=lambda a: (a[1], a[0])):
        caption = f"({task}), {label}"
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
    grouped: dict[str, list[Any]] = {}
    for r in sorted(selection.tunes.values(), key=lambda r: r.info.run_id):
        name = (
            f"{r.data.params.get('controller.name', '?')}, "
            f"{labels.tuning(*labels.tune_criterion(r))}"
        )
        grouped.setdefault(name, []).append(r)
    if grouped:
        gains = "; ".join(
            f"{html.escape(name)} ("
            + ", ".join(f"<a href='{_run_link(ui, r)}'>{r.info.run_id[:8]}</a>" for r in runs)
            + ")"
            for name, runs in sorted(grouped.items())
        )
        items.append(f"<li>Gains tuned by cuckoo search in: {gains}.</li>")
    if summary_table is not None:
        items += _verdict_items(summary_table)
    return ["<h2>At a glance</h2>", "<ul class='glance'>", *items, "</ul>"]


def _verdict_items(summary_table: tables.Table) -> list[str]:
    """Per agent and baseline: held-out success and the two verdicts; after each agent's rows
    the ablation's sentence."""
    conv, acc = (f"verdict (≈ {100 * c.claimed:.0f} %)" for c in claims.CLAIMS)
    by_agent: dict[str, list[str]] = {}
    sentences: dict[str, str] = {}
    shown = summary_table.shown.to_dict("records")
    for row, numbers in zip(shown, summary_table.numbers.to_dict("records"), strict=True):
        e = {k: html.escape(str(v)) for k, v in row.items()}
        against = f" against <b>{e['Baseline']}</b>" if row["Baseline"] != "–" else ""
        by_agent.setdefault(e["Agent"], []).append(
            f"<li><b>{e['Agent']}</b>, {e['Proposed']}{against}: held-out success "
            f"{e['Held-out success, proposed']} with the proposed control, "
            f"{e['Held-out success, baseline']} with the baseline; paper tasks reached "
            f"{e['Paper tasks reached']}; convergence claim <i>{e[conv]}</i>, accuracy claim "
            f"<i>{e[acc]}</i>.</li>"
        )
        if numbers.get("adaptation"):
            sentences[e["Agent"]] = html.escape(str(numbers["adaptation"]))
    items = []
    for agent, rows in by_agent.items():
        items += rows
        if agent in sentences:
            items.append(f"<li><b>{agent}</b>: {sentences[agent]}</li>")
    return items
