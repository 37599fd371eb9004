"""What a report reads from the store: the agents behind the eval runs, their episodes, the
context each table states, the tune and training histories, and the runs used.

Each eval run's agent (preset, learning aids, budget spent) comes from its train run
(`armexp.report.agent`); the eval run's own ``agent.*`` params are its stage defaults, not the
policy's. Its labels (what each controller was, how it was tuned, what it is compared with) come
from its ``controllers.yaml`` (`armexp.report.labels`; older runs: ``adaptive`` against
``pid_gaing``). Its ``<label>.<task>.<metric>`` metrics override ``episodes.csv`` for the paper
tasks; the ``eval.*`` offsets and ``robot.torque_limit`` params go into the footnotes.
"""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import yaml

from armexp import paper
from armexp.config import ConfigError
from armexp.paper import TASKS
from armexp.report import formatting, labels
from armexp.report.agent import AgentInfo, agent_info, caption
from armexp.report.labels import Label
from armexp.report.runs import Reader, Selection, metric_value
from armexp.tracking.tags import (
    ADAPTIVE_GAINS_TAG,
    AGENT_PRESET_TAG,
    COMMIT_TAG,
    STAGE_TAG,
    TRAIN_RUN_TAG,
)

#: What `armexp eval` animates: ``animations/<label>/<task>.<format>`` artifacts.
ANIMATIONS_DIR = "animations"
ANIMATION_FORMATS = ("gif", "mp4")


def agents_of(selection: Selection, configs: dict[str, Any]) -> dict[str, AgentInfo]:
    """The agent behind each eval run (by eval run id), from its train run."""
    out = {}
    for ev in selection.evals:
        tid = ev.data.tags.get(TRAIN_RUN_TAG, "")
        info = agent_info(tid, selection.trains.get(tid), configs.get(tid))
        if ev.data.tags.get(ADAPTIVE_GAINS_TAG) == "config":
            info.gains = _gains_label(ev)
        out[ev.info.run_id] = info
    return out


def _gains_label(ev: Any) -> str:
    """How an eval run with ``eval.adaptive_gains=config`` is named: "paper gains" when its
    logged ``controller.gains.*`` are the paper's."""
    published = paper.GAINS
    logged = {k: _param(ev.data.params.get(f"controller.gains.{k}")) for k in published}
    same = all(
        isinstance(v, int | float) and math.isclose(float(v), published[k])
        for k, v in logged.items()
    )
    return "paper gains" if same else "configured gains"


def check_one_setting(selection: Selection, configs: dict[str, Any]) -> None:
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


def missing_seeds(selection: Selection, seeds: list[int]) -> str | None:
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


def _stored_labels(metrics: dict[str, float]) -> list[str]:
    """The labels an eval run logged metrics for (``<label>.<task or random>.<metric>``)."""
    return list(dict.fromkeys(k.split(".", 1)[0] for k in sorted(metrics) if k.count(".") >= 2))


def labels_of(selection: Selection, reader: Reader) -> dict[str, dict[str, Label]]:
    """Each eval run's labels by reported name (by eval run id), from its ``controllers.yaml``
    or, for runs made before it, from the labels its metrics name."""
    out = {}
    for ev in selection.evals:
        declared = reader.yaml(ev.info.run_id, labels.CONTROLLERS_FILE)
        out[ev.info.run_id] = labels.of_run(
            declared,
            _stored_labels(ev.data.metrics),
            ev.data.tags,
            ev.data.params,
            selection.tunes,
        )
    return out


def episodes_of(
    selection: Selection,
    reader: Reader,
    agents: dict[str, AgentInfo],
    run_labels: dict[str, dict[str, Label]],
) -> pd.DataFrame:
    """Every episode of the selected eval runs (``episodes.csv``), with the agent that ran it
    and its label's columns (`armexp.report.labels.annotate`), and the eval run's
    ``<label>.<task>.<metric>`` metrics over the paper tasks' rows (the same numbers where both
    exist; a metric ±inf, stored as ±float max, reads as ±inf)."""
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
        _task_metrics_onto(frame, ev.data.metrics)
        frames.append(labels.annotate(frame, run_labels.get(run_id, {})))
    if not frames:
        raise ConfigError(
            "the report has nothing to show: the selected eval runs have no episodes.csv "
            "artifact (were their artifacts deleted?)."
        )
    return pd.concat(frames, ignore_index=True)


def _task_metrics_onto(frame: pd.DataFrame, metrics: dict[str, float]) -> None:
    """Write each ``<label>.<task>.<metric>`` metric of a paper task into that label's rows of
    that task, in the column ``<metric>``: one aligned assignment per metric name (an eval run
    logs hundreds of them), where a value exists."""
    stored = set(frame.controller.astype(str))
    found = []
    for name, value in metrics.items():
        label, _, rest = name.partition(".")
        task, _, key = rest.partition(".")
        if label in stored and task in TASKS and key and "." not in key:
            found.append((label, task, key, metric_value(value)))
    if not found:
        return
    long = pd.DataFrame(found, columns=["controller", "task", "key", "value"]).assign(has=1.0)
    wide = long.pivot(index=["controller", "task"], columns="key", values=["value", "has"])
    rows = pd.MultiIndex.from_arrays([frame.controller.astype(str), frame.task.astype(str)])
    on_tasks = frame.task.isin(list(TASKS)).to_numpy() & rows.isin(wide.index)
    aligned = wide.reindex(rows)
    for key in sorted(long.key.unique()):
        where = on_tasks & aligned["has", key].notna().to_numpy()  # a NaN metric is written too
        if where.any():
            frame.loc[where, key] = aligned["value", key].to_numpy()[where]


def _values(texts: list[str | None], show: Any) -> str | None:
    """One logged param over the eval runs, shown; None when no run logs it."""
    shown = list(dict.fromkeys(show(v) for v in map(_param, texts) if v is not None))
    if not shown:
        return None
    return shown[0] if len(shown) == 1 else " / ".join(shown) + " (differs between runs)"


def _per_joint(value: Any, unit: str, sign: str = "") -> str:
    values = value if isinstance(value, list) else [value]
    return ", ".join(f"{sign}{float(v):g}" for v in values) + f" {unit}"


def context_of(
    selection: Selection, agents: dict[str, AgentInfo], train_cfg: dict[str, Any] | None
) -> formatting.Context:
    """What Table III, the controller comparison and the claim check say beside their numbers."""
    infos = list({a.label: a for a in agents.values()}.values())
    counts = [sum(a.label == i.label for a in agents.values()) for i in infos]
    params = [ev.data.params for ev in selection.evals]
    limit = _values(
        [p.get("robot.torque_limit") for p in params], lambda v: _per_joint(v, "N·m", "±")
    )
    if limit is None and train_cfg and train_cfg.get("robot", {}).get("torque_limit"):
        limit = _per_joint(train_cfg["robot"]["torque_limit"], "N·m", "±")
    env = (train_cfg or {}).get("env", {})
    return formatting.Context(
        agent=caption(infos, counts),
        initial_offset=_values(
            [p.get("eval.initial_offset") for p in params], lambda v: _per_joint(v, "rad")
        ),
        large_offset=_values(
            [p.get("eval.large_offset") for p in params], lambda v: _per_joint(v, "rad")
        ),
        torque_limit=limit,
        reach_threshold=float(env.get("reach_threshold", 0.04)),
        action_period=float(env.get("action_period", 0.03)),
        plain_missing=any(a.aided for a in infos)
        and not any(a.known and not a.aids for a in infos),
    )


def training_curves(selection: Selection, reader: Reader) -> dict[str, dict[str, pd.DataFrame]]:
    curves = {}
    for run_id, run in sorted(selection.trains.items()):
        preset = run.data.tags.get(AGENT_PRESET_TAG) or run.data.params.get("agent.name", "?")
        label = f"{preset}, seed {run.data.params.get('seed', '?')} ({run_id[:8]})"
        curves[label] = {
            "success": reader.history(run_id, "rollout/success_rate_100"),
            "reward": reader.history(run_id, "episode/reward"),
            "held_out": reader.history(run_id, "eval/success_rate"),
        }
    return curves


def held_out_histories(selection: Selection, reader: Reader) -> dict[str, pd.DataFrame]:
    """Each train run's held-out checks during training (``eval/success_rate``: step, value)."""
    return {run_id: reader.history(run_id, "eval/success_rate") for run_id in selection.trains}


def held_out_curves(
    histories: dict[str, pd.DataFrame], agents: dict[str, AgentInfo]
) -> dict[str, list[pd.DataFrame]]:
    """Held-out success histories per agent preset, one per train run."""
    by_train = {a.train_run: a for a in agents.values()}
    groups: dict[str, list[pd.DataFrame]] = {}
    for run_id in sorted(histories):
        history = histories[run_id]
        info = by_train.get(run_id)
        if not len(history) or info is None:
            continue
        label = f"{info.preset} ({'aided' if info.aided else 'plain'})"
        groups.setdefault(label, []).append(history)
    return groups


def runs_table(selection: Selection, agents: dict[str, AgentInfo]) -> pd.DataFrame:
    """One row per run used; ``agent`` is the train run's preset (an eval run's own
    ``agent.*`` params are its stage defaults, not the policy's)."""
    by_train = {a.train_run: a for a in agents.values()}
    rows = []
    for run in selection.all_runs:
        p = run.data.params
        stage = run.data.tags.get(STAGE_TAG, "")
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
                "git_commit": run.data.tags.get(COMMIT_TAG, "")[:10],
            }
        )
    return pd.DataFrame(rows).drop_duplicates("run_id")


def headline(episodes: pd.DataFrame) -> dict[str, float]:
    out: dict[str, float] = {"eval_runs": float(episodes.eval_run.nunique())}
    for label, rows in episodes.groupby("controller"):
        tasks = rows[rows.task.isin(list(TASKS))]
        rand = rows[rows.task.str.startswith("random_")]
        out[f"{label}.tasks.success_rate"] = float(tasks.success.mean()) if len(tasks) else math.nan
        out[f"{label}.random.success_rate"] = float(rand.success.mean()) if len(rand) else math.nan
    return out


def animations_of(
    run_id: str, run_labels: dict[str, Label], reader: Reader, folder: Path
) -> list[tuple[str, str, dict[str, str]]]:
    """The eval run's animations of the paper tasks, copied into ``folder`` under
    ``animations/<label>/<task>.<format>``: (label, task, {format: path relative to ``folder``})
    for each that has a GIF; ``run_labels`` gives each label's stored folder name."""
    source = reader.path(run_id, ANIMATIONS_DIR)
    if source is None:
        return []
    out = []
    for name, lab in run_labels.items():
        for task in TASKS:
            files = {}
            for fmt in ANIMATION_FORMATS:
                path = source / lab.stored / f"{task}.{fmt}"
                if path.is_file():
                    relative = f"{ANIMATIONS_DIR}/{name}/{task}.{fmt}"
                    (folder / relative).parent.mkdir(parents=True, exist_ok=True)
                    shutil.copyfile(path, folder / relative)
                    files[fmt] = relative
            if "gif" in files:
                out.append((name, task, files))
    return out
