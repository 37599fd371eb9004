"""`armexp play`: a trained policy on chosen tasks and targets, animated.

The policy, its environment and its controllers are loaded as `armexp eval` loads them
(`armexp.stages.controller_set`): the policy of ``play.train_run`` or of the latest FINISHED train
run for the configured robot and obstacles, tracked by the label ``play.controller`` (null: the
policy's own controller, e.g. ``adaptive``; ``adaptive_off``; or a baseline such as ``pid_itae``)
with the gains of ``play.adaptive_gains``, or for a baseline ``play.baseline_gains`` /
``play.tune_runs.<label>`` (`armexp.gains.resolve`). One episode per task of ``play.tasks`` (names
of ``tasks.targets``) and per extra target of ``play.targets`` (named ``target_<i>``), each with the
reset seed eval gives it (``seed`` + the task's place in ``tasks.targets``; extra targets after the
tasks), so a task plays the episode eval measured.

Logged to a play run tagged with the train run (and ``armexp.tune_run.<label>`` when the gains
came from a tune run): ``animations/<label>/<name>.gif|mp4`` (``play.formats``), the 1 kHz
trajectory ``trajectories/<label>/<name>.parquet``, the episodes' metrics as rows of
``episodes.csv`` and as ``<label>.<name>.<metric>``.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any
from urllib.parse import unquote, urlparse

import mlflow
import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig, open_dict

from armexp.agents.rollout import episode_metrics, rollout
from armexp.config import ConfigError
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv
from armexp.sim.trajectory import trajectory_columns
from armexp.stages import animate
from armexp.stages.controller_set import as_run, lineage_tags, load_policy, play_entry
from armexp.tracking import artifacts, stage_runs


def _episodes(cfg: DictConfig, env: ReachEnv) -> list[tuple[str, dict[str, Any], int]]:
    """(name, reset options, seed) of each episode: the tasks, then the extra targets."""
    order = list(env.settings.tasks)
    out: list[tuple[str, dict[str, Any], int]] = [
        (str(t), {"task": str(t)}, int(cfg.seed) + order.index(str(t))) for t in cfg.play.tasks
    ]
    for i, target in enumerate(cfg.play.targets):
        point = np.array([float(v) for v in target])
        _check_reachable(env, i, point)
        out.append((f"target_{i}", {"target": point}, int(cfg.seed) + len(order) + i))
    return out


def _check_reachable(env: ReachEnv, i: int, point: np.ndarray) -> None:
    """An extra target must lie in the policy's target workspace (the targets its environment
    draws), which the config check cannot see: it depends on the joint limits and on the
    environment of the train run."""
    s = env.settings
    nearest = float(np.min(np.linalg.norm(env.workspace.points - point, axis=1)))
    if nearest > s.reach_threshold:
        raise ConfigError(
            f"play.targets[{i}]=[{point[0]:g}, {point[1]:g}] is not allowed: the policy's "
            f"environment draws no target within {s.reach_threshold:g} m of it (its targets are "
            f"reachable within the joint limits in {s.max_target_time:g} s with the tip clear of "
            f"the obstacles, at least {s.target_margin:g} m from them and "
            f"{s.min_target_distance:g} m from the start; the nearest is {nearest:.3f} m away)."
        )


def _local(uri: str) -> str:
    """An artifact URI as a path when it is a local folder."""
    parsed = urlparse(uri)
    return unquote(parsed.path) if parsed.scheme in ("", "file") else uri


def run(cfg: DictConfig) -> stage_runs.StageResult:
    policy = load_policy(cfg, "play")
    entry = play_entry(cfg, policy)
    label, gains = entry.label, entry.gains.values
    cfg = as_run(cfg, policy, "play")
    with open_dict(cfg):  # the run's params and name record the label that played
        cfg.play.controller = label
    env = ReachEnv(settings_from_config(policy.train_cfg, entry.controller, gains), record=True)
    episodes = _episodes(cfg, env)
    n, threshold = env.n, env.settings.reach_threshold
    lengths = env.settings.plant.arm.lengths_array
    formats = [str(f) for f in cfg.play.formats]
    tags = {**policy.tags, **lineage_tags([entry])}
    with stage_runs.stage_run(cfg, "play", run_name=cfg.play.run_name, extra_tags=tags) as active:
        mlflow.log_text(yaml.safe_dump(gains, sort_keys=False), f"gains/{label}.yaml")
        records, seconds = [], []
        for name, options, seed in episodes:
            episode = rollout(
                env, policy.model, options, seed=seed, deterministic=bool(cfg.play.deterministic)
            )
            metrics = episode_metrics(episode, n, lengths, threshold)
            finite = {k: v for k, v in metrics.items() if math.isfinite(v)}
            mlflow.log_metrics({f"{label}.{name}.{k}": v for k, v in finite.items()})
            frame = pd.DataFrame(episode.rows, columns=[*trajectory_columns(n), "target_error"])
            artifacts.log_dataframe(frame, f"{name}.parquet", f"trajectories/{label}")
            task = name if "task" in options else None
            what = animate.describe(task, episode.target)
            still = animate.scene(env, label, what, episode.target, episode.reason)
            seconds.append(animate.log_animation(frame, still, label, name, formats))
            records.append(
                {"controller": label, "task": name, "reason": episode.reason, "seed": seed,
                 "target_x": episode.target[0], "target_y": episode.target[1], **metrics}
            )  # fmt: skip
        artifacts.log_dataframe(pd.DataFrame(records), "episodes.csv")
        summary = {"episodes": float(len(records)),
                   "success_rate": float(np.mean([r["success"] for r in records])),
                   "animation_seconds": float(np.mean(seconds))}  # fmt: skip
        mlflow.log_metrics(summary)
        where = Path(_local(mlflow.get_artifact_uri(f"{animate.ANIMATIONS_DIR}/{label}")))
        reached = sum(r["reason"] == "reached" for r in records)
        print(
            f"play: run {active.info.run_id} | {label}, {reached}/{len(records)} reached | "
            f"animations ({', '.join(formats)}) of {', '.join(r['task'] for r in records)} in "
            f"{where}"
        )
        return stage_runs.StageResult(active.info.run_id, summary)
