"""`armexp eval`: a trained policy on tasks (a)–(d) and held-out random targets, with the tuned
adaptive controller and with the tuned PID baseline in the loop (docs/design.md §8, Table III).

The policy, the environment (robot, obstacles, env settings) and the adaptive gains are those of
the train run (``eval.train_run`` or the latest FINISHED one for the configured robot and
obstacles); the targets come from this run's ``tasks`` config. Both controllers see the same
targets and the same disturbance draws (same reset seed per episode).

Logged: per controller and task the metrics of `armexp.agents.rollout.episode_metrics` as
``<controller>.<task>.<metric>``; per controller the aggregate over random targets
(``<controller>.random.success_rate`` …); every episode as rows of ``episodes.csv``; the 1 kHz
trajectory of each paper task per controller as ``trajectories/<controller>/<task>.parquet``
(the simulate stage's columns plus ``target_error``; random targets too with
``eval.random_trajectories=true``); with ``eval.animations`` (default) each paper task's episode
per controller animated as ``animations/<controller>/<task>.gif`` and ``.mp4``
(`armexp.render.animation`).

Convergence (docs/design.md §8): each paper task is run a second time for
``eval.convergence_window`` seconds with the reference started ``eval.initial_offset`` rad from the
arm on every joint. ``<controller>.<task>.convergence_time`` is the 2 % settling time of the
offset's effect on e1 (this run's e1 minus the unperturbed episode's), ``e1_settling_time`` that of
‖e1‖ itself, which never settles when the steady tracking error exceeds 2 % of the offset
(`armexp.agents.rollout.settling_time`); the run's trajectory is
``trajectories/<controller>/<task>_offset.parquet``.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass
from typing import Any

import mlflow
import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig, OmegaConf

from armexp import console, run_names, tracking
from armexp.agents.callbacks import MODEL_DIR, MODEL_FILE
from armexp.agents.rollout import Episode, episode_metrics, rollout, settling_time
from armexp.agents.sac import load_sac
from armexp.config import ConfigError
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv
from armexp.render.animation import FORMATS
from armexp.sim.trajectory import trajectory_columns
from armexp.stages import animate

log = logging.getLogger(__name__)

TRAIN_RUN_TAG = "armexp.train_run"
PID_TUNE_RUN_TAG = "armexp.pid_tune_run"
#: Where the adaptive controller's gains came from: ``tuned`` (the policy's) or ``config``.
GAINS_TAG = "armexp.adaptive_gains"
#: Short controller labels used in metric names.
LABELS = {"subsystem_adaptive": "adaptive", "pid": "pid"}


def _train_run(cfg: DictConfig, section: str = "eval") -> Any:
    return tracking.find_stage_run(
        cfg,
        "train",
        run_id=cfg[section].train_run,
        # The circles too: a run with overridden circles keeps its obstacle set's name.
        match={
            "robot.name": str(cfg.robot.name),
            "obstacles.name": str(cfg.obstacles.name),
            "obstacles.circles": tracking.flatten(cfg)["obstacles.circles"],
        },
        key=f"{section}.train_run",
    )


def _pid_gains(
    cfg: DictConfig, train_cfg: DictConfig, section: str = "eval"
) -> tuple[dict[str, Any], dict[str, str]]:
    if cfg[section].pid_gains == "config":
        from armexp.config import compose_config

        robot = str(train_cfg.robot.name)
        pid = compose_config(["controller=pid", f"robot={robot}"]).controller
        gains = OmegaConf.to_container(pid.gains)
        assert isinstance(gains, dict)
        return {str(k): v for k, v in gains.items()}, {}
    run, gains = tracking.tuned_gains(
        train_cfg, cfg[section].pid_tune_run, key=f"{section}.pid_tune_run", controller="pid"
    )
    return gains, {PID_TUNE_RUN_TAG: run.info.run_id}


@dataclass
class Policy:
    """A train run's policy, the config it was trained with (its environment; the episode
    targets are the caller's ``tasks``), the gains of each controller it runs with, and the
    lineage tags of the run that uses it."""

    train_id: str
    train_cfg: DictConfig
    model: Any
    gains: dict[str, dict[str, Any]]
    tags: dict[str, str]


def load_policy(cfg: DictConfig, section: str, controllers: list[str], key: str) -> Policy:
    """The policy of ``<section>.train_run`` (or the latest matching train run) with the gains of
    ``controllers``: the adaptive ones per ``<section>.adaptive_gains``, the PID's per
    ``<section>.pid_gains`` / ``<section>.pid_tune_run``. ``key`` names the config key that
    chose the controllers."""
    stage = cfg[section]
    train_run = _train_run(cfg, section)
    train_id = train_run.info.run_id
    train_cfg = OmegaConf.load(tracking.download_artifact(train_id, "config.yaml", cfg))
    assert isinstance(train_cfg, DictConfig)
    # The episode targets are this run's choice; the environment is the policy's.
    train_cfg.tasks = cfg.tasks
    trained_with = str(train_cfg.controller.name)
    adaptive_gains: Any
    if stage.adaptive_gains == "config":
        if str(cfg.controller.name) != trained_with:
            raise ConfigError(
                f"{section}.adaptive_gains=config is not allowed with "
                f"controller={cfg.controller.name}: the policy was trained with {trained_with}; "
                f"compose controller={trained_with}."
            )
        adaptive_gains = OmegaConf.to_container(cfg.controller.gains, resolve=True)
    else:
        adaptive_gains = yaml.safe_load(
            tracking.download_artifact(train_id, "gains.yaml", cfg).read_text()
        )
    unknown = [c for c in controllers if c not in LABELS]
    if unknown:
        raise ConfigError(f"{key}={controllers} is not allowed: choose from {sorted(LABELS)}.")
    gains: dict[str, dict[str, Any]] = {trained_with: adaptive_gains}
    tags = {TRAIN_RUN_TAG: train_id, GAINS_TAG: str(stage.adaptive_gains)}
    if stage.adaptive_gains == "tuned" and train_run.data.tags.get("armexp.tune_run"):
        tags["armexp.tune_run"] = train_run.data.tags["armexp.tune_run"]
    if train_run.data.tags.get(run_names.AGENT_PRESET_TAG):  # the run is named after the policy
        tags[run_names.AGENT_PRESET_TAG] = train_run.data.tags[run_names.AGENT_PRESET_TAG]
    for name in controllers:
        if name not in gains:
            if name != "pid":
                raise ConfigError(
                    f"{key} contains {name}, but the policy was trained with "
                    f"{trained_with} and only pid can be added as a baseline."
                )
            gains[name], pid_tags = _pid_gains(cfg, train_cfg, section)
            tags.update(pid_tags)
    model_path = tracking.download_artifact(train_id, f"{MODEL_DIR}/{MODEL_FILE}", cfg)
    model = load_sac(str(model_path), None, train_cfg.agent)
    return Policy(train_id, train_cfg, model, {c: gains[c] for c in controllers}, tags)


def _targets(cfg: DictConfig, env: ReachEnv) -> list[tuple[str, dict[str, Any]]]:
    """(task name, reset options): the paper tasks, then ``random_<i>`` held-out targets."""
    out: list[tuple[str, dict[str, Any]]] = []
    if cfg.eval.paper_tasks:
        out += [(name, {"task": name}) for name in env.settings.tasks]
    rng = np.random.default_rng(int(cfg.tasks.random_seed))
    for i in range(int(cfg.tasks.n_random)):
        out.append((f"random_{i:03d}", {"target": env.workspace.sample(rng)}))
    return out


def run(cfg: DictConfig) -> tracking.StageResult:
    controllers = [str(c) for c in cfg.eval.controllers]
    loaded = load_policy(cfg, "eval", controllers, "eval.controllers")
    train_cfg, policy, gains, tags = loaded.train_cfg, loaded.model, loaded.gains, loaded.tags

    with tracking.stage_run(cfg, "eval", run_name=cfg.eval.run_name, extra_tags=tags) as active:
        for name in controllers:
            mlflow.log_text(
                yaml.safe_dump(gains[name], sort_keys=False), f"gains/{LABELS[name]}.yaml"
            )
        records = []
        summary: dict[str, float] = {}
        started = time.perf_counter()
        bar = None
        try:
            for name in controllers:
                label = LABELS[name]
                env = ReachEnv(settings_from_config(train_cfg, name, gains[name]), record=True)
                n = env.n
                lengths = env.settings.plant.arm.lengths_array
                threshold = env.settings.reach_threshold
                targets = _targets(cfg, env)
                if bar is None:
                    total = len(controllers) * len(targets)
                    bar = console.progress_bar(cfg.eval.progress, total, "eval", "episode")
                for index, (task, options) in enumerate(targets):
                    episode = rollout(
                        env, policy, options, seed=int(cfg.seed) + index,
                        deterministic=bool(cfg.eval.deterministic),
                    )  # fmt: skip
                    metrics = episode_metrics(episode, n, lengths, threshold)
                    if not task.startswith("random_"):
                        perturbed = _offset_run(cfg, env, policy, options, int(cfg.seed) + index)
                        window = float(cfg.eval.convergence_window)
                        metrics["convergence_time"] = settling_time(perturbed, n, window, episode)
                        metrics["e1_settling_time"] = settling_time(perturbed, n, window)
                        tracking.log_dataframe(
                            pd.DataFrame(
                                perturbed.rows, columns=[*trajectory_columns(n), "target_error"]
                            ),
                            f"{task}_offset.parquet",
                            f"trajectories/{label}",
                        )
                    records.append(
                        {"controller": label, "task": task, "reason": episode.reason,
                         "target_x": episode.target[0], "target_y": episode.target[1], **metrics}
                    )  # fmt: skip
                    if not task.startswith("random_"):
                        finite = {k: v for k, v in metrics.items() if math.isfinite(v)}
                        mlflow.log_metrics({f"{label}.{task}.{k}": v for k, v in finite.items()})
                    if not task.startswith("random_") or cfg.eval.random_trajectories:
                        frame = pd.DataFrame(
                            episode.rows, columns=[*trajectory_columns(n), "target_error"]
                        )
                        tracking.log_dataframe(frame, f"{task}.parquet", f"trajectories/{label}")
                    if cfg.eval.animations and not task.startswith("random_"):
                        what = animate.describe(task, episode.target)
                        still = animate.scene(env, label, what, episode.target, episode.reason)
                        animate.log_animation(frame, still, label, task, FORMATS)
                    if bar is not None:
                        bar.update(1)
                table = pd.DataFrame([r for r in records if r["controller"] == label])
                summary.update(_aggregate(label, table))
        except BaseException:
            if records:  # an interrupted or failed eval keeps the episodes it ran
                tracking.log_dataframe(pd.DataFrame(records), "episodes.csv")
            raise
        finally:
            if bar is not None:
                bar.close()
        frame = pd.DataFrame(records)
        tracking.log_dataframe(frame, "episodes.csv")
        mlflow.log_metrics({k: v for k, v in summary.items() if math.isfinite(v)})
        _print_summary(active.info.run_id, loaded.train_id, frame, time.perf_counter() - started)
        return tracking.StageResult(active.info.run_id, summary)


def _offset_run(
    cfg: DictConfig, env: ReachEnv, policy: Any, options: dict[str, Any], seed: int
) -> Episode:
    """The task's episode with the reference started ``eval.initial_offset`` from the arm, for
    the first ``eval.convergence_window`` seconds."""
    window = float(cfg.eval.convergence_window)
    steps = math.ceil(window / env.settings.action_period - 1e-9)
    offset = [float(cfg.eval.initial_offset)] * env.n
    return rollout(
        env, policy, {**options, "reference_offset": offset}, seed=seed,
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
        for key in ("target_time", "final_error_cm", "convergence_time"):
            if key in won.columns:  # convergence: paper tasks only
                out[f"{label}.{group}.mean_{key}"] = (
                    float(won[key].mean()) if len(won) else math.nan
                )
        for key in ("rms_e1", "tip_rms_cm", "time_at_limit"):
            out[f"{label}.{group}.mean_{key}"] = float(rows[key].mean())
    return out


def _print_summary(run_id: str, train_id: str, frame: pd.DataFrame, wall: float) -> None:
    """One line: per controller, the random targets' success and collision rates and the paper
    tasks reached (the report and ``episodes.csv`` have every episode)."""
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
        parts.append(text)
    print(" | ".join([*parts, f"{wall:.1f} s"]))
