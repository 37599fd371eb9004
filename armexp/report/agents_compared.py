"""What the aids buy (``tables/agents.{md,tex,csv}``): every agent of the report side by side, one
row each — aided or not, its step budget, the environment steps its held-out checks first reached
90 %, its last check, held-out success and paper tasks with the proposed control in `armexp eval`.
Shown when the report holds two agents or more (an aided preset, the non-privileged one,
Table II's SAC at speed: `experiment=reproduce` with ``pipeline.agents``)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pandas as pd

from armexp.paper import TASKS
from armexp.report.agent import AgentInfo
from armexp.report.comparison import held_out_success
from armexp.report.episodes import agent_names, agents, of_agent, proposed_labels
from armexp.report.formatting import Table, iqm_cell

#: The held-out success a policy counts as competent at (the non-privileged goal's 90 %).
COMPETENT = 0.9


def first_step_at(history: pd.DataFrame, level: float = COMPETENT) -> float:
    """The first check's step with success ≥ ``level`` (nan: never)."""
    hit = history[history.value >= level]
    return float(hit.step.iloc[0]) if len(hit) else math.nan


def _steps(value: float) -> str:
    if not math.isfinite(value):
        return "–"
    return f"{value / 1e6:.2g} M" if value >= 1e6 else f"{value / 1e3:.0f} k"


def agents_table(
    episodes: pd.DataFrame,
    infos: Mapping[str, AgentInfo],
    histories: Mapping[str, pd.DataFrame],
) -> Table | None:
    """One row per agent of ``episodes`` (None with fewer than two). ``infos``: the agent of each
    eval run; ``histories``: each train run's held-out checks (``step``, ``value``)."""
    if len(agents(episodes)) < 2:
        return None
    names = agent_names(episodes)
    found = proposed_labels(episodes)
    proposed = found[0] if found else ""
    rows = [
        _row(of_agent(episodes, a), names.get(a, str(a)), proposed, infos, histories)
        for a in agents(episodes)
    ]
    notes = [
        "Per agent over its seeds: the environment steps it trained for (median); the first "
        f"held-out check during training at ≥ {COMPETENT * 100:.0f} % success (median over the "
        "runs that got there); the last check's success (IQM [95 % CI], %); in `armexp eval`, "
        "the held-out success and the paper tasks reached with the proposed control "
        f"({proposed or '–'}), IQM [95 % CI] over eval runs. Compare rows at equal environment "
        "steps: each row says its own.",
    ]
    return Table(
        "agents",
        "The agents side by side (what the aids buy)",
        pd.DataFrame([shown for shown, _ in rows]),
        pd.DataFrame([numbers for _, numbers in rows]),
        notes,
    )


def _row(
    rows: pd.DataFrame, label: str, proposed: str, infos: Mapping[str, AgentInfo],
    histories: Mapping[str, pd.DataFrame],
) -> tuple[dict[str, str], dict[str, object]]:  # fmt: skip
    """One agent's cells (shown) and numbers (CSV)."""
    runs = list(dict.fromkeys(rows.eval_run))
    trains = list(dict.fromkeys(infos[r].train_run for r in runs if r in infos))
    budget = np.array([infos[r].spent.get("env_steps", math.nan) for r in runs if r in infos])
    env_steps = float(np.nanmedian(budget)) if np.isfinite(budget).any() else math.nan
    curves = [histories[t] for t in trains if t in histories and len(histories[t])]
    first = np.array([first_step_at(c) for c in curves], dtype=float)
    first = first[np.isfinite(first)]
    to_competent = float(np.median(first)) if first.size else math.nan
    last_text, last = iqm_cell(np.array([c.value.iloc[-1] for c in curves], float) * 100.0, 1)
    success_text, success = held_out_success(rows, proposed) if proposed else ("–", {})
    tasks = rows[(rows.controller == proposed) & rows.task.astype(str).isin(TASKS)]
    tasks_text, reached = iqm_cell(tasks.groupby("eval_run").success.sum().to_numpy(float), 1)
    aided = bool(rows.aided.iloc[0]) if "aided" in rows.columns else False
    if not curves:
        first_text = "–"
    elif first.size:
        first_text = f"{_steps(to_competent)} ({first.size} of {len(curves)} runs)"
    else:
        first_text = f"not reached (0 of {len(curves)})"
    shown = {
        "Agent": label, "Aided": "yes" if aided else "no", "Seeds": str(len(runs)),
        "Env steps": _steps(env_steps),
        f"Steps to {COMPETENT * 100:.0f} % (held-out checks)": first_text,
        "Last check": f"{last_text} %" if curves else "–",
        "Held-out success": success_text,
        f"Tasks reached (of {len(TASKS)})": tasks_text,
    }  # fmt: skip
    numbers: dict[str, object] = {
        "agent": label, "aided": aided, "seeds": len(runs), "env_steps": env_steps,
        "steps_to_competent_median": to_competent, "runs_competent": int(first.size),
        "runs_with_checks": len(curves), "last_check_iqm": last["iqm"] / 100.0,
        "held_out_success_iqm": success.get("iqm", math.nan) / 100.0,
        "tasks_reached_iqm": reached["iqm"],
    }  # fmt: skip
    return shown, numbers
