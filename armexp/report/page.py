"""The report's tables, figures and ``index.html`` (`armexp.report.index`), written into one
folder from what `armexp.report.gather` read."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
from omegaconf import DictConfig

from armexp.paper import TASKS
from armexp.report import (
    agents_compared,
    claims,
    comparison,
    figures,
    formatting,
    gather,
    hpo,
    index,
    labels,
    performance,
    seed_figures,
    summary,
    tables,
    tuning,
)
from armexp.report.agent import AgentInfo
from armexp.report.episodes import agent_names, proposed_labels
from armexp.report.runs import Reader, Selection
from armexp.tracking.tags import TRAIN_RUN_TAG

#: Above this many train runs the per-run training curves give way to the across-seed ones.
MAX_TRAINING_CURVES = 4


def build(selection: Selection, reader: Reader, folder: Path, cfg: DictConfig) -> dict[str, float]:
    """Every table and figure of the report into ``folder``; returns headline numbers."""
    reader.know(selection.all_runs)
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
    histories = gather.held_out_histories(selection, reader)
    made = _tables(episodes, ctx, train_cfg, agents, train_id, tunes)
    compared = agents_compared.agents_table(episodes, agents, histories)
    if compared is not None:
        made.insert(1, compared)
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
    _run_figures(selection, reader, agents, episodes, histories, save)
    _cso_figure(shown, run_labels[shown], tunes, save)
    animations = gather.animations_of(shown, run_labels[shown], reader, folder)
    index.write(folder, made, pictures, animations, runs_frame, selection, cfg, ctx.agent)
    return gather.headline(episodes)


def _tables(
    episodes: pd.DataFrame,
    ctx: formatting.Context,
    train_cfg: dict[str, Any] | None,
    agents: dict[str, AgentInfo],
    train_id: str,
    tunes: list[dict[str, Any]],
) -> list[formatting.Table]:
    """The report's tables, the summary first; the ablation, tuning and CSO tables only where
    the selection has something to put in them."""
    made: list[formatting.Table] = []
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


def _cso_figure(
    shown: str,
    shown_labels: dict[str, labels.Label],
    tunes: list[dict[str, Any]],
    save: Callable[[Any, str, str], None],
) -> None:
    """The CSO convergence of the tune runs behind eval run ``shown`` (else of every one)."""
    ids = {lab.tune_run for lab in shown_labels.values() if lab.tune_run}
    drawn = [t for t in tunes if t["run_id"] in ids] or tunes
    if not drawn:
        return
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
    proposed = proposed_labels(first)
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
    histories: dict[str, pd.DataFrame],
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
    groups = gather.held_out_curves(histories, agents)
    if groups:
        save(
            seed_figures.learning_curves_ci(groups, n_boot=formatting.N_BOOT),
            "learning_curves",
            "Learning curves: held-out success of the policy as it trained, IQM across seeds "
            "with a 95 % stratified bootstrap band, per agent preset.",
        )
    short = agent_names(episodes)
    named = episodes.assign(agent=episodes.agent.map(short)) if short else episodes
    profiles = seed_figures.performance_profiles(named, n_boot=formatting.N_BOOT)
    if profiles is not None:
        save(
            profiles,
            "performance_profiles",
            "Performance profiles on the held-out targets, every controller label: the share of "
            "runs above each success rate and of episodes below each tip tracking error, with "
            "95 % stratified bootstrap bands across seeds.",
        )
