"""The report's ``index.html``: at a glance (what ran, held-out success and the claim check's
verdicts), the tables, the figures and animations, the runs used with links to the MLflow UI,
and the command that regenerates it."""

from __future__ import annotations

import html
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import DictConfig

from armexp.report import claims, formatting, labels
from armexp.report.runs import Selection


def write(
    folder: Path,
    made: list[formatting.Table],
    pictures: list[tuple[str, str]],
    animations: list[tuple[str, str, dict[str, str]]],
    runs_frame: pd.DataFrame,
    selection: Selection,
    cfg: DictConfig,
    agent: str,
) -> None:
    """``index.html``: the glance, the agent, every table and figure, the animations, the runs
    used (linked to the MLflow UI) and the command that regenerates the report."""
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


def _glance(
    summary_table: formatting.Table | None, selection: Selection, cfg: DictConfig
) -> list[str]:
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


def _verdict_items(summary_table: formatting.Table) -> list[str]:
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
