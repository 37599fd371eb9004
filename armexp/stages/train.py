"""`armexp train`: the agent of ``agent.algo`` (SAC, Algorithm 1, by default) plans joint
velocities with the tuned controller in the loop.

Gains come from a tune run (``train.tune_run`` or the latest FINISHED tune run for the same
controller and robot under ``tuner.objective.criterion``; its id is tagged ``armexp.tune_run``)
or, with ``train.gains=config``, from ``controller.gains`` (gains typed on the command,
``controller.gains=paper``, select that unless ``train.gains`` is typed too:
`armexp.gains.train_source`); `armexp.gains.resolve` finds them.

Streams to MLflow while training: SB3's own metrics (``train/*``, ``rollout/*``, ``time/*``) and,
per episode, reward, length, success and collision with their rates over the last 100 episodes.
The learning aids of ``agent.aids`` (`armexp.agents.addons`: planner demonstrations, behaviour
cloning, the DAgger expert, weight averaging) are built from their ``_target_`` and applied in
order, then the callbacks of ``train.callbacks`` (by default the held-out checks, which with
``train.eval_every`` > 0 run the policy on held-out targets while training: ``eval/*``).
Artifacts: ``gains.yaml`` (the controller in the loop), ``checkpoint/`` (model without replay
buffer + ``state.json``, overwritten every ``train.checkpoint_every`` steps; on interruption
with the replay buffer, `armexp.agents.kept_buffer`)
and ``model/`` (the final model). ``armexp train train.resume=<run id>`` reopens a KILLED or
FAILED run and continues from its checkpoint with the run's own config.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import mlflow
import torch
import yaml
from omegaconf import DictConfig, OmegaConf
from stable_baselines3.common.callbacks import CallbackList
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from armexp import console, disk
from armexp.agents import kept_buffer
from armexp.agents.addons import TrainingAddOn, TrainingContext, build_addons
from armexp.agents.callbacks import (
    CHECKPOINT_DIR,
    MODEL_DIR,
    MODEL_FILE,
    STATE_FILE,
    Budget,
    Checkpoint,
    EpisodeStats,
    MLflowOutputFormat,
    PaceLine,
    Progress,
    log_model,
)
from armexp.agents.factory import build_agent, load_agent, mark_resumed, usage
from armexp.agents.vec import make_vec_env
from armexp.config import ConfigError
from armexp.envs.factory import settings_from_config
from armexp.gains import job_overrides, resolve, with_train_source
from armexp.reads import Reads
from armexp.tracking import artifacts, liveness, lookup, remote, run_end, stage_runs
from armexp.tracking.tags import (
    AGENT_ALGO_TAG,
    AGENT_LEFT_OUT_TAG,
    AGENT_MAPPED_TAG,
    AGENT_PRESET_TAG,
    GAINS_SOURCE_TAG,
    RESUMED_TAG,
    STOP_REASON_TAG,
    TUNE_RUN_TAG,
)

log = logging.getLogger(__name__)

#: What the stage hashed before its reads were declared, a list kept by hand.
_HASHED_BEFORE_DECLARATIONS = (
    "seed", "robot", "obstacles", "controller", "env", "agent", "train.gains", "train.tune_run",
)  # fmt: skip
#: What the stage hashed before ``tuner.seed`` chose its default tune run (its runs carry
#: that digest; `armexp.tracking.reuse` still takes them where their config matches).
_HASHED_BEFORE_TUNER_SEED = (
    "seed", "robot", "obstacles", "controller", "env", "agent", "train.gains", "train.tune_run",
    "train.callbacks", "tuner.objective.criterion",
)  # fmt: skip
#: What train reads of the config (`armexp.reads`): the seed, the environment (robot, obstacles,
#: ``env``; no named tasks: training draws its targets), the controller in the loop and where its
#: gains come from (``train.gains``, ``train.tune_run``, or the latest tune run under
#: ``tuner.objective.criterion``, of ``tuner.seed`` first), the agent with its aids, and the
#: callbacks. Where it records (run name, store, checkpoints, logging interval, progress bar),
#: the run it resumes and its torch threads are not hashed.
READS = Reads(
    "train",
    hashed=(*_HASHED_BEFORE_TUNER_SEED, "tuner.seed"),
    unhashed=("train.run_name", "train.resume", "train.progress", "train.torch_threads",
              "train.checkpoint_every", "train.log_every", "tracking"),
    earlier=(_HASHED_BEFORE_TUNER_SEED, _HASHED_BEFORE_DECLARATIONS),
)  # fmt: skip


def controller_gains_for(cfg: DictConfig) -> tuple[dict[str, Any], dict[str, str]]:
    """The gains the agent trains with, in config form, and the lineage tags that say where
    they came from (`armexp.gains.resolve`: ``controller.gains``, or ``train.tune_run`` or the
    latest tune run of this controller and robot under ``tuner.objective.criterion``)."""
    found = resolve(
        cfg, str(cfg.controller.name), str(cfg.robot.name), str(cfg.train.gains),
        run_id=cfg.train.tune_run, key="train.tune_run",
    )  # fmt: skip
    if found.tune_run is None:
        return found.values, {GAINS_SOURCE_TAG: "config"}
    return found.values, {GAINS_SOURCE_TAG: "tune", TUNE_RUN_TAG: found.tune_run}


def _agent_preset(cfg: DictConfig) -> str:
    """The agent's name in runs and reports: ``agent.name``, which is the ``agent`` config group
    option it composed unless a study put another preset in its place
    (`armexp.stages.study`) or the command named it (``agent.name=sac_plain_hpo``: a preset's
    values changed, compared in a report as an agent of its own)."""
    return str(cfg.agent.name)


def step_budget(cfg: DictConfig) -> int:
    """Upper bound on environment steps: every episode at full length, or ``max_env_steps``."""
    bound = int(cfg.agent.episodes) * int(cfg.env.max_steps)
    cap = cfg.agent.max_env_steps
    return bound if cap is None else min(bound, int(cap))


def run(composed: DictConfig, addons: Sequence[TrainingAddOn] = ()) -> stage_runs.StageResult:
    """Train on `READS`' view of the composed config, its ``train.gains`` as the command meant it
    (`armexp.gains.with_train_source`); the run logs that config whole. ``addons``: the caller's
    own, after those of the config (an HPO trial's pruning)."""
    composed = with_train_source(composed, job_overrides())
    cfg = READS.view(composed)
    if cfg.train.resume:
        return resume(composed)
    # A bad add-on stops here, before a run exists.
    algo = str(cfg.agent.algo)
    build_addons(cfg.agent.aids, algo=algo)
    build_addons(cfg.train.callbacks, "train.callbacks", algo)
    gains, tags = controller_gains_for(cfg)
    tags[AGENT_PRESET_TAG] = _agent_preset(cfg)
    tags.update(_algo_tags(cfg.agent, tags[AGENT_PRESET_TAG]))
    with stage_runs.stage_run(
        composed, "train", run_name=cfg.train.run_name, extra_tags=tags, reads=READS
    ) as active:
        mlflow.log_text(yaml.safe_dump(gains, sort_keys=False), "gains.yaml")
        summary = _learn(cfg, gains, active.info.run_id, None, {}, _gains_from(tags), addons)
        return stage_runs.StageResult(active.info.run_id, summary)


def resume(composed: DictConfig, check_overrides: bool = True) -> stage_runs.StageResult:
    """Continue a KILLED/FAILED train run from its checkpoint, in the same MLflow run, with the
    run's own config (``check_overrides=False``: the caller knows the composed config matches
    the run's inputs, e.g. the pipeline with ``pipeline.reuse``). Both configs are read through
    `READS`."""
    cfg = READS.view(composed)
    run_id = str(cfg.train.resume)
    found = lookup.find_stage_run(
        cfg, "train", run_id=run_id, key="train.resume", statuses=("KILLED", "FAILED", "RUNNING")
    )
    if liveness.is_alive(found):
        raise ConfigError(
            f"train.resume={run_id} is not allowed: that run is still training in another "
            f"process (its last heartbeat was {liveness.heartbeat_age(found):.0f} s ago); wait "
            "for it to end or stop it first."
        )
    try:
        state_path = artifacts.download_artifact(run_id, f"{CHECKPOINT_DIR}/{STATE_FILE}", cfg)
    except Exception:
        raise ConfigError(
            f"train.resume={run_id} is not allowed: that run has no checkpoint yet (it stopped "
            "before its first one); start a new run instead."
        ) from None
    state = json.loads(state_path.read_text())
    model_path = artifacts.download_artifact(run_id, f"{CHECKPOINT_DIR}/{MODEL_FILE}", cfg)
    buffer_path = None
    if state.get(kept_buffer.STATE_KEY):
        buffer_path = str(artifacts.download_artifact(
            run_id, f"{CHECKPOINT_DIR}/{kept_buffer.BUFFER_FILE}", cfg))  # fmt: skip
    original = OmegaConf.load(artifacts.download_artifact(run_id, "config.yaml", cfg))
    assert isinstance(original, DictConfig)
    original.tracking = composed.tracking
    original.train.progress = composed.train.progress
    if check_overrides:
        _apply_resume_overrides(original, cfg, run_id)
    gains = yaml.safe_load(artifacts.download_artifact(run_id, "gains.yaml", cfg).read_text())
    how = "with its replay buffer" if buffer_path else "its replay buffer refilled by the policy"
    print(f"train: resuming run {run_id} from step {state['num_timesteps']}, {how}")
    with stage_runs.stage_run(
        original,
        "train",
        resume_run_id=run_id,
        extra_tags={RESUMED_TAG: str(state["num_timesteps"])},
        reads=READS,
    ):
        # The interruption that stopped it is over: the run ends with its own new status.
        run_end.clear_error(mlflow.MlflowClient(), run_id)
        origin = _gains_from(found.data.tags)
        summary = _learn(
            READS.view(original), gains, run_id, str(model_path), state, origin,
            buffer_path=buffer_path,
        )  # fmt: skip
        return stage_runs.StageResult(run_id, summary)


#: Keys a resume may change: where it logs, how it shows progress, and the budget to extend.
RESUME_KEYS = ("train.resume", "train.progress", "train.torch_threads", "tracking.",
               "agent.max_env_steps", "agent.max_minutes", "agent.episodes", "hydra.")  # fmt: skip


def _apply_resume_overrides(original: DictConfig, cfg: DictConfig, run_id: str) -> None:
    """A resume continues the run with its own config; budget overrides extend it, anything
    else on the command line would be ignored, so it is refused."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return
    differing = _differing(original, cfg)
    for override in HydraConfig.get().overrides.task:
        key = override.partition("=")[0].lstrip("+~")
        # The run's own command typed again (with train.resume added) changes nothing: only
        # an override that composes into another config is refused.
        if not key.startswith(RESUME_KEYS) and differing:
            raise ConfigError(
                f"{override} is not allowed with train.resume={run_id}: a resumed run keeps the "
                f"config it started with (this would change {_named(key, differing)}); only "
                "its budget (agent.max_env_steps, agent.max_minutes, agent.episodes) and "
                "tracking.* may change."
            )
        if key.startswith("agent."):
            OmegaConf.update(original, key, OmegaConf.select(cfg, key))


def _differing(original: DictConfig, cfg: DictConfig) -> list[str]:
    """The keys train's result depends on (`READS`), outside `RESUME_KEYS`, whose values differ
    between the run's config and the one the command line composes."""

    def leaves(node: Any, prefix: str) -> dict[str, Any]:
        if isinstance(node, dict):
            out: dict[str, Any] = {}
            for k, v in node.items():
                out.update(leaves(v, f"{prefix}.{k}"))
            return out
        return {prefix: node}

    def values(config: DictConfig) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for key in READS.hashed:
            node = OmegaConf.select(config, key)
            plain = (
                OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node
            )
            out.update(leaves(plain, key))
        return out

    ours, theirs = values(original), values(cfg)
    keys = set(ours) | set(theirs)
    return sorted(k for k in keys if not k.startswith(RESUME_KEYS) and ours.get(k) != theirs.get(k))


def _named(key: str, differing: list[str]) -> str:
    """The override's own key where it is among the changes, else the first few changes."""
    inside = [k for k in differing if k == key or k.startswith(f"{key}.")]
    return ", ".join((inside or differing)[:3])


def _algo_tags(agent: DictConfig, preset: str) -> dict[str, str]:
    """The run's algorithm and, said on one line too, the preset's options that it maps to
    another meaning or leaves out (`armexp.agents.factory.usage`)."""
    used = usage(agent)
    tags = {AGENT_ALGO_TAG: used.algo}
    line = used.line(preset)
    if line:
        print(f"train: {line}")
        tags[AGENT_LEFT_OUT_TAG] = ",".join(used.left_out) or "none"
        if used.mapped:
            tags[AGENT_MAPPED_TAG] = ";".join(f"{k}={v}" for k, v in used.mapped.items())
    return tags


def _gains_from(tags: dict[str, str]) -> str:
    """Where the controller's gains came from, for the summary line."""
    if tags.get(GAINS_SOURCE_TAG) == "config":
        return "gains from the config"
    return f"gains of tune run {tags.get(TUNE_RUN_TAG, '?')[:8]}"


def _learn(
    cfg: DictConfig,
    gains: dict[str, Any],
    run_id: str,
    model_path: str | None,
    state: dict[str, Any],
    gains_from: str,
    extra: Sequence[TrainingAddOn] = (),
    buffer_path: str | None = None,
) -> dict[str, float]:
    agent, tr = cfg.agent, cfg.train
    algo = str(agent.algo)
    addons = [
        *build_addons(agent.aids, algo=algo),
        *build_addons(tr.callbacks, "train.callbacks", algo),
        *extra,
    ]
    if tr.torch_threads:
        torch.set_num_threads(int(tr.torch_threads))
    settings = settings_from_config(cfg, gains=gains, with_tasks=False)
    venv = make_vec_env(settings, int(agent.n_envs), str(agent.vec_env), int(cfg.seed))
    if model_path is None:
        model = build_agent(agent, venv, int(cfg.seed))
    else:
        model = load_agent(model_path, venv, agent)
        if buffer_path is not None and isinstance(model, OffPolicyAlgorithm):
            kept_buffer.restore(model, Path(buffer_path))
        else:  # refill an empty replay buffer with the policy before updates resume
            mark_resumed(model, int(agent.learning_starts))
    model.set_logger(Logger(folder=None, output_formats=[MLflowOutputFormat(run_id)]))
    done_steps = int(state.get("num_timesteps", 0))
    total = step_budget(cfg)
    stats = EpisodeStats(run_id, int(tr.log_every), start_episode=int(state.get("episodes", 0)))
    stats.wall_offset = float(state.get("wall_s", 0.0))
    stats.recent.extend((bool(s), bool(c)) for s, c in state.get("recent", []))
    minutes = agent.max_minutes
    budget = Budget(
        stats, int(agent.episodes), total, None if minutes is None else float(minutes) * 60.0
    )

    def snapshot() -> dict[str, Any]:
        return {
            "num_timesteps": int(model.num_timesteps),
            "episodes": stats.episodes,
            "wall_s": stats.wall(),
            # The rolling window of the last episodes, so a resumed run's rates go on from it.
            "recent": [[bool(s), bool(c)] for s, c in stats.recent],
        }

    checkpoint = Checkpoint(int(tr.checkpoint_every), snapshot)
    callbacks: list[Any] = [stats, budget, checkpoint]
    # Inside the wall-time budget: `stats` started its clock above.
    context = TrainingContext(
        model, settings, int(cfg.seed), resumed=model_path is not None,
        budget_used=lambda: budget.used(model.num_timesteps), wall=stats.wall, run_id=run_id,
        stats=stats,
    )  # fmt: skip
    for addon in addons:
        callbacks += addon.setup(context)
    if console.shows_progress(tr.progress):
        callbacks.append(Progress(total, stats, initial=done_steps))
    else:
        callbacks.append(PaceLine(total, stats, budget.seconds))
    started = time.perf_counter()
    try:
        model.learn(
            total_timesteps=max(total - done_steps, 0),
            callback=CallbackList(callbacks),
            log_interval=4,
            reset_num_timesteps=model_path is None,
        )
    except BaseException as exc:
        # Interrupted or failed: keep what was learned so `train.resume` can continue it; on a
        # full disk or a store that stopped answering the last complete checkpoint stays, as
        # more writes would fail too.
        if not disk.is_full(exc) and not remote.is_lost(exc):
            with run_end.while_stopping(exc):
                stats.flush()
                checkpoint.save(with_buffer=True)
        raise
    finally:
        venv.close()
    elapsed = time.perf_counter() - started
    stats.flush()
    checkpoint.save()
    if model_path is not None:  # a buffer kept for this resume is stale now
        kept_buffer.discard(run_id, f"{CHECKPOINT_DIR}/{kept_buffer.BUFFER_FILE}")
    kept: dict[str, float] = {}
    for addon in addons:
        kept.update(addon.finish(context))
    log_model(model, MODEL_DIR, snapshot())
    steps = int(model.num_timesteps)
    summary = {
        **kept,
        "final/env_steps": float(steps),
        "final/episodes": float(stats.episodes),
        "final/success_rate_100": stats.success_rate,
        "final/collision_rate_100": stats.collision_rate,
        "final/wall_s": stats.wall(),
        "final/env_steps_per_s": (steps - done_steps) / elapsed if elapsed > 0 else 0.0,
    }
    mlflow.log_metrics(summary)
    mlflow.set_tag(STOP_REASON_TAG, budget.reason or "steps")
    print(
        f"train: run {run_id} | {gains_from} | {steps} steps, {stats.episodes} episodes, "
        f"{stats.wall():.0f} s | success (last 100) {stats.success_rate:.2f}, collisions "
        f"{stats.collision_rate:.2f} | stopped on {budget.reason or 'steps'}"
    )
    return summary
