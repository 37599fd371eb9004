"""`armexp eval`: a trained policy on tasks (a)–(d) and held-out random targets, with its own
controller, the ablation and the baselines in the loop (docs/design.md §4, §8, Table III).

The policy, the environment (robot, obstacles, env settings) and its own gains are those of the
train run (``eval.train_run`` or the latest FINISHED one for the configured robot and obstacles);
the targets come from this run's ``tasks`` config. The controllers, their labels and gains are
`armexp.stages.controller_set`'s: the policy's own controller (``adaptive``), ``adaptive_off``
(``eval.ablation``), each baseline of ``eval.baselines`` and the ``adaptive_<criterion>``
references a baseline needs. Every label sees the same targets and the same disturbance draws
(same reset seed per episode).

Logged: ``controllers.yaml`` (per label: controller, role, criterion, horizon, tune run, gains,
compare_with) and ``gains/<label>.yaml``; the tags ``armexp.tune_run.<label>`` of every label whose
gains came from a tune run; per label and paper task the metrics of
`armexp.agents.rollout.episode_metrics` and the convergence metrics below as
``<label>.<task>.<metric>``; per label the aggregate over random targets
(``<label>.random.success_rate`` …) and over the paper tasks (``<label>.tasks.…``); every episode
as rows of ``episodes.csv`` (with the label's ``criterion``); the 1 kHz trajectory of each paper
task per label as ``trajectories/<label>/<task>.parquet`` (the simulate stage's columns plus
``target_error``; random targets too with ``eval.random_trajectories=true``); with
``eval.animations`` (default) each paper task's episode per label animated as
``animations/<label>/<task>.gif`` and ``.mp4`` (`armexp.render.animation`).

Convergence (Definition 1, eqs. 9–10; `armexp.sim.convergence`): each paper task is run again
for ``eval.convergence_window`` s with the reference started ``eval.initial_offset`` rad from the
arm on every joint (small: the torques do not saturate), and once more at ``eval.large_offset``.
From ‖e1‖ of those runs: ``decay_rate`` (1/s), ``ultimate_bound`` (rad), ``decay_overshoot``,
``settling_time`` (s, to the band max(2 % of the offset, ``eval.convergence_tolerance``)) and
``itae`` (rad·s²); the large offset's carry the suffix ``_large``. Their trajectories are
``trajectories/<label>/<task>_offset.parquet`` and ``<task>_offset_large.parquet``.
"""

from __future__ import annotations

import math
import time
from typing import Any

import mlflow
import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig

from armexp import console
from armexp.agents.rollout import Episode, convergence_metrics, episode_metrics, rollout
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv
from armexp.reads import Reads
from armexp.render.animation import FORMATS
from armexp.sim.trajectory import trajectory_columns
from armexp.stages import animate
from armexp.stages.controller_set import (
    CONTROLLERS_FILE,
    Entry,
    as_run,
    controller_set,
    lineage_tags,
    load_policy,
)
from armexp.tracking import artifacts, run_end, stage_runs

#: The perturbed runs of a paper task: (``eval`` key of the offset, metric and file suffix).
PERTURBATIONS = (("initial_offset", ""), ("large_offset", "_large"))
#: What the stage hashed before its reads were declared, a list kept by hand.
_HASHED_BEFORE_DECLARATIONS = (
    "seed", "tasks", "eval.train_run", "eval.baselines", "eval.ablation", "eval.baseline_gains",
    "eval.tune_runs", "eval.adaptive_gains", "controller.gains", "eval.paper_tasks",
    "eval.deterministic", "eval.initial_offset", "eval.large_offset", "eval.convergence_window",
    "eval.convergence_tolerance", "tuner.objective.criterion", "tuner.objective.horizon",
)  # fmt: skip
#: What the stage hashed before ``tuner.seed`` chose its default tune run (its runs carry
#: that digest; `armexp.tracking.reuse` still takes them where their config matches).
_HASHED_BEFORE_TUNER_SEED = (
    "seed", "eval", "tasks", "robot.name", "obstacles", "controller.name", "controller.gains",
    "tuner.objective.criterion",
)  # fmt: skip
#: What eval reads of the config (`armexp.reads`): ``eval`` (the policy's train run, the labels
#: and where their gains come from, the convergence runs, what is logged), the targets
#: (``tasks``) and the seed of the episodes; the train run is looked up by robot and obstacles,
#: the tune runs by ``tuner.objective.criterion`` and ``tuner.seed``, and
#: ``eval.adaptive_gains=config`` (or a baseline's configured gains) reads ``controller.name``
#: and ``controller.gains``. The policy's environment is its train run's config, so the
#: ``eval.train_run`` id hashes it. The progress bar, run name and store are not hashed.
READS = Reads(
    "eval",
    hashed=(*_HASHED_BEFORE_TUNER_SEED, "tuner.seed"),
    unhashed=("eval.progress", "eval.run_name", "tracking"),
    earlier=(_HASHED_BEFORE_TUNER_SEED, _HASHED_BEFORE_DECLARATIONS),
)  # fmt: skip


def _targets(cfg: DictConfig, env: ReachEnv) -> list[tuple[str, dict[str, Any]]]:
    """(task name, reset options): the paper tasks, then ``random_<i>`` held-out targets."""
    out: list[tuple[str, dict[str, Any]]] = []
    if cfg.eval.paper_tasks:
        out += [(name, {"task": name}) for name in env.settings.tasks]
    rng = np.random.default_rng(int(cfg.tasks.random_seed))
    for i in range(int(cfg.tasks.n_random)):
        out.append((f"random_{i:03d}", {"target": env.workspace.sample(rng)}))
    return out


def run(composed: DictConfig) -> stage_runs.StageResult:
    """Evaluate on `READS`' view of the composed config; the run logs the composed config."""
    cfg = READS.view(composed)
    policy = load_policy(cfg, "eval")
    entries = controller_set(cfg, policy)
    tags = {**policy.tags, **lineage_tags(entries)}
    composed = as_run(composed, policy, "eval")
    with stage_runs.stage_run(
        composed, "eval", run_name=cfg.eval.run_name, extra_tags=tags, reads=READS
    ) as active:
        described = {e.label: e.record() for e in entries}
        mlflow.log_text(yaml.safe_dump(described, sort_keys=False), CONTROLLERS_FILE)
        for entry in entries:
            values = yaml.safe_dump(entry.gains.values, sort_keys=False)
            mlflow.log_text(values, f"gains/{entry.label}.yaml")
        records: list[dict[str, Any]] = []
        summary: dict[str, float] = {}
        started = time.perf_counter()
        bar = None
        try:
            for entry in entries:
                env = ReachEnv(
                    settings_from_config(policy.train_cfg, entry.controller, entry.gains.values),
                    record=True,
                )
                targets = _targets(cfg, env)
                if bar is None:
                    total = len(entries) * len(targets)
                    bar = console.progress_bar(cfg.eval.progress, total, "eval", "episode")
                for index, (task, options) in enumerate(targets):
                    seed = int(cfg.seed) + index
                    records.append(_episode(cfg, env, policy.model, entry, task, options, seed))
                    if bar is not None:
                        bar.update(1)
                table = pd.DataFrame([r for r in records if r["controller"] == entry.label])
                summary.update(_aggregate(entry.label, table))
        except BaseException as exc:
            if records:  # an interrupted or failed eval keeps the episodes it ran
                with run_end.while_stopping(exc):
                    artifacts.log_dataframe(pd.DataFrame(records), "episodes.csv")
            raise
        finally:
            if bar is not None:
                bar.close()
        frame = pd.DataFrame(records)
        artifacts.log_dataframe(frame, "episodes.csv")
        mlflow.log_metrics({k: v for k, v in summary.items() if math.isfinite(v)})
        _print_summary(active.info.run_id, policy.train_id, frame, time.perf_counter() - started)
        return stage_runs.StageResult(active.info.run_id, summary)


def _episode(
    cfg: DictConfig,
    env: ReachEnv,
    model: Any,
    entry: Entry,
    task: str,
    options: dict[str, Any],
    seed: int,
) -> dict[str, Any]:
    """One episode of ``entry``'s label (and, for a paper task, its perturbed runs), logged:
    its ``episodes.csv`` row."""
    label, n = entry.label, env.n
    paper_task = not task.startswith("random_")
    deterministic = bool(cfg.eval.deterministic)
    episode = rollout(env, model, options, seed=seed, deterministic=deterministic)
    lengths = env.settings.plant.arm.lengths_array
    metrics = episode_metrics(episode, n, lengths, env.settings.reach_threshold)
    if paper_task:
        for key, suffix in PERTURBATIONS:
            offset = cfg.eval[key]
            if offset is None:
                continue
            perturbed = _offset_run(cfg, env, model, options, seed, float(offset))
            window = float(cfg.eval.convergence_window)
            tolerance = float(cfg.eval.convergence_tolerance)
            measured = convergence_metrics(perturbed, n, float(offset), window, tolerance)
            metrics.update({f"{k}{suffix}": v for k, v in measured.items()})
            artifacts.log_dataframe(
                _frame(perturbed, n), f"{task}_offset{suffix}.parquet", f"trajectories/{label}"
            )
        finite = {k: v for k, v in metrics.items() if math.isfinite(v)}
        mlflow.log_metrics({f"{label}.{task}.{k}": v for k, v in finite.items()})
    if paper_task or cfg.eval.random_trajectories:
        frame = _frame(episode, n)
        artifacts.log_dataframe(frame, f"{task}.parquet", f"trajectories/{label}")
        if cfg.eval.animations and paper_task:
            what = animate.describe(task, episode.target)
            still = animate.scene(env, label, what, episode.target, episode.reason)
            animate.log_animation(frame, still, label, task, FORMATS)
    return {"controller": label, "criterion": entry.gains.criterion, "task": task,
            "reason": episode.reason, "target_x": episode.target[0],
            "target_y": episode.target[1], **metrics}  # fmt: skip


def _frame(episode: Episode, n: int) -> pd.DataFrame:
    return pd.DataFrame(episode.rows, columns=[*trajectory_columns(n), "target_error"])


def _offset_run(
    cfg: DictConfig, env: ReachEnv, policy: Any, options: dict[str, Any], seed: int, offset: float
) -> Episode:
    """The task's episode with the reference started ``offset`` rad from the arm on every joint,
    for the first ``eval.convergence_window`` seconds."""
    window = float(cfg.eval.convergence_window)
    steps = math.ceil(window / env.settings.action_period - 1e-9)
    return rollout(
        env, policy, {**options, "reference_offset": [offset] * env.n}, seed=seed,
        deterministic=bool(cfg.eval.deterministic), max_steps=steps,
    )  # fmt: skip


def _aggregate(label: str, table: pd.DataFrame) -> dict[str, float]:
    out: dict[str, float] = {}
    for group, rows in (("random", table[table.task.str.startswith("random_")]),
                        ("tasks", table[~table.task.str.startswith("random_")])):  # fmt: skip
        if rows.empty:
            continue
        won = rows[rows.success > 0]
        out[f"{label}.{group}.success_rate"] = float(rows.success.mean())
        out[f"{label}.{group}.collision_rate"] = float(rows.collision.mean())
        out[f"{label}.{group}.episodes"] = float(len(rows))
        for key in ("target_time", "final_error_cm"):
            out[f"{label}.{group}.mean_{key}"] = float(won[key].mean()) if len(won) else math.nan
        for key in ("rms_e1", "tip_rms_cm", "time_at_limit", "decay_rate", "ultimate_bound"):
            if key in rows.columns:  # convergence: paper tasks only
                out[f"{label}.{group}.mean_{key}"] = float(rows[key].mean())
    return out


def _print_summary(run_id: str, train_id: str, frame: pd.DataFrame, wall: float) -> None:
    """One line: per label, the random targets' success and collision rates, the paper tasks
    reached and their mean decay rate (the report and ``episodes.csv`` have every episode)."""
    parts = [f"eval: run {run_id}", f"policy of train run {train_id[:8]}"]
    for label, rows in frame.groupby("controller", sort=False):
        rand = rows[rows.task.str.startswith("random_")]
        tasks = rows[~rows.task.str.startswith("random_")]
        text = f"{label}:"
        if len(rand):
            text += (
                f" success {rand.success.mean():.2f}, collisions {rand.collision.mean():.2f} "
                f"on {len(rand)} targets"
            )
        if len(tasks):
            won = [str(t) for t in tasks.task[tasks.success > 0]]
            text += f"{',' if len(rand) else ''} tasks reached {len(won)}/{len(tasks)}"
            text += f" ({', '.join(won)})" if won else ""
            rate = tasks.decay_rate.mean() if "decay_rate" in tasks else math.nan
            text += f", decay {rate:.3g}/s" if math.isfinite(rate) else ""
        parts.append(text)
    print(" | ".join([*parts, f"{wall:.1f} s"]))
