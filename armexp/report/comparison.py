"""The controller comparison (every label the eval runs ran) and the ablation (adaptation on
against off), over the selected eval runs (docs/design.md §4, §8, §9).

Each cell of the comparison is the IQM over runs × paper tasks (tip RMS: runs × every episode)
with a 95 % stratified bootstrap CI, the runs resampled within each task; a task whose value is
not finite in some run (never settled, not logged) is left out of that cell and the cell says
how many tasks it covers. The ablation compares the proposed adaptive law with the same law with
adaptation off (b1 = 0, so ρ̂ ≡ 0) on the episodes both ran, by the relative change of the tip
tracking error and of the time constant 1/α when adaptation is switched off.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp import paper
from armexp.report import labels, stats
from armexp.report.episodes import (
    agent_columns,
    agent_names,
    agents,
    of_agent,
    run_counts,
    with_derived,
)
from armexp.report.formatting import (
    N_BOOT,
    Context,
    Table,
    context_notes,
    iqm_cell,
    number,
    pct,
    statistics_note,
)

#: The comparison's measured columns: (header, key, paper tasks only, digits).
COLUMNS = (
    ("Tip RMS (cm)", "tip_rms_cm", False, 3),
    ("Decay rate α (1/s)", "decay_rate", True, 3),
    ("Ultimate bound α* (mrad)", "ultimate_bound_mrad", True, 3),
    ("α, large offset (1/s)", "decay_rate_large", True, 3),
    ("α*, large offset (mrad)", "ultimate_bound_large_mrad", True, 3),
    ("Settling time (s)", "settling_time", True, 3),
    ("ITAE (rad·s²)", "itae", True, 3),
    ("Peak |τ| (N·m)", "max_torque", True, 1),
    ("Time at limit (s)", "time_at_limit", True, 3),
)
#: What the ablation compares: (what, key, paper tasks only, reached by both).
ABLATION = (
    ("tip RMS error", "tip_rms_cm", False, True),
    ("time constant 1/α", "time_constant", True, False),
)


def held_out_success(rows: pd.DataFrame, label: str) -> tuple[str, dict[str, float]]:
    """Held-out success of ``label`` per eval run (seed), IQM [CI] over the runs, in %."""
    held = rows[(rows.controller == label) & rows.task.astype(str).str.startswith("random_")]
    if held.empty:
        return "–", {"iqm": math.nan, "ci_low": math.nan, "ci_high": math.nan, "n": 0}
    per_run = held.groupby("eval_run").success.mean().to_numpy(dtype=float) * 100.0
    text, got = iqm_cell(per_run, 1)
    targets = int(held.groupby("eval_run").size().max())
    return f"{text} % of {targets}", got


def matrix_cell(rows: pd.DataFrame, key: str, digits: int = 3) -> tuple[str, dict[str, float]]:
    """IQM [95 % CI] of ``key`` over runs × episodes (the episodes are the strata), over the
    episodes with a finite value in every run; says how many episodes when some are left out."""
    empty = {"iqm": math.nan, "ci_low": math.nan, "ci_high": math.nan, "episodes": 0}
    if key not in rows.columns or rows.empty:
        return "–", empty
    table = rows.pivot_table(
        index="eval_run", columns="task", values=key, aggfunc="first", dropna=False
    )
    m = table.to_numpy(dtype=float)
    keep = np.all(np.isfinite(m), axis=0)
    m = m[:, keep]
    if m.size == 0:
        return "–", empty
    if m.shape[0] == 1:
        point, low, high = float(stats.iqm(m)), math.nan, math.nan
        text = number(point, digits)
    else:
        point, low, high = stats.iqm_ci(m, n_boot=N_BOOT)
        text = f"{number(point, digits)} [{number(low, digits)}, {number(high, digits)}]"
    if not keep.all():
        text += f" ({int(keep.sum())}/{keep.size} tasks)"
    return text, {"iqm": point, "ci_low": low, "ci_high": high, "episodes": int(keep.sum())}


def comparison(episodes: pd.DataFrame, ctx: Context | None = None) -> Table:
    """One row per label (and agent): its role, controller and tuning, held-out success, tip
    RMS, Definition-1 convergence at both offsets, settling time, ITAE, peak |τ| and time at
    the torque limit."""
    ctx = ctx or Context()
    ep = with_derived(episodes)
    names = agent_names(ep)
    shown_rows, numbers = [], []
    for agent in agents(ep):
        sub = of_agent(ep, agent)
        for label in labels.ordered(sub):
            got = labels.info(sub, label)
            rows = sub[sub.controller == label]
            shown: dict[str, Any] = {}
            if names:
                shown["Agent"] = names[agent]
            shown.update(
                {
                    "Label": label,
                    "Role": got["role"],
                    "Controller": got["controller_name"],
                    "Tuned under": labels.tuning(got["criterion"], got["horizon"]),
                    "Compared with": got["compare_with"] or "–",
                }
            )
            row: dict[str, Any] = {"label": label, **agent_columns(rows, agent), **got}
            shown["Held-out success"], success = held_out_success(sub, label)
            row.update({f"heldout_success_pct_{k}": v for k, v in success.items()})
            for header, key, tasks_only, digits in COLUMNS:
                part = rows[rows.task.isin(paper.TASKS)] if tasks_only else rows
                shown[header], value = matrix_cell(part, key, digits)
                row.update({f"{key}_{k}" if k != "iqm" else key: v for k, v in value.items()})
            shown_rows.append(shown)
            numbers.append(row)
    small = f" ({ctx.initial_offset})" if ctx.initial_offset else ""
    large = f" ({ctx.large_offset})" if ctx.large_offset else " (where logged)"
    notes = [
        "Role: proposed (the policy's own controller), reference (the proposed law tuned under "
        "a baseline's criterion: the proposed side of that baseline's comparison), ablation (the "
        "adaptive law with adaptation off, b1 = 0), baseline (compared with the label named). "
        "Tuned under: the cuckoo search's criterion and horizon, or configured gains.",
        "Held-out success: IQM over the runs of each run's share of held-out targets reached. "
        "Tip RMS: over every episode (paper tasks and held-out targets); the other columns over "
        "the paper tasks (a)–(d). Decay rate α and ultimate bound α*: the Definition-1 fit of "
        f"‖e1‖ after the small initial offset{small} and after the large one{large}; settling "
        "time and ITAE at the small offset. (k/4 tasks): the tasks with a finite value in every "
        "run (never settled or not logged: left out); – : none (eval runs made before these "
        "measures do not log them).",
        statistics_note(*run_counts(ep)),
        *context_notes(ctx),
    ]
    return Table(
        "comparison_controllers",
        "Controller comparison: the proposed control, its ablation and the baselines (same "
        "policy, same targets)",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )


def paired(
    rows: pd.DataFrame, key: str, first: str, second: str, tasks_only: bool, reached: bool
) -> tuple[np.ndarray, np.ndarray]:
    """(first, second) score matrices (runs × episodes) of two labels over the episodes both
    ran with a finite, positive ``key`` in every run (and, with ``reached``, both reached)."""
    if tasks_only:
        rows = rows[rows.task.isin(paper.TASKS)]
    rows = rows[rows.controller.isin([first, second])]
    if key not in rows.columns or rows.empty:
        return np.zeros((0, 0)), np.zeros((0, 0))
    table = rows.pivot_table(index="eval_run", columns=["task", "controller"],
                             values=[key, "success"], aggfunc="first", dropna=False)  # fmt: skip
    keep = []
    for task in sorted({t for t, _ in table[key].columns}):
        ok = True
        for label in (first, second):
            if (task, label) not in table[key].columns:
                ok = False
                break
            value = table[key][(task, label)].to_numpy(dtype=float)
            ok &= bool(np.all(np.isfinite(value) & (value > 0)))
            if reached:
                ok &= bool(np.all(table["success"][(task, label)].to_numpy(dtype=float) > 0))
        if ok:
            keep.append(task)
    a = np.array([table[key][(t, first)].to_numpy(dtype=float) for t in keep]).T
    b = np.array([table[key][(t, second)].to_numpy(dtype=float) for t in keep]).T
    return a.reshape(len(table), len(keep)), b.reshape(len(table), len(keep))


def _change(on: np.ndarray, off: np.ndarray) -> tuple[float, float, float]:
    """(IQM off − IQM on) / IQM on with its CI (none for one run), nan without episodes."""
    if on.size == 0:
        return math.nan, math.nan, math.nan
    if on.shape[0] < 2:
        base = float(stats.iqm(on))
        return (float(stats.iqm(off)) - base) / base if base > 0 else math.nan, math.nan, math.nan
    return stats.relative_improvement_ci(off, on, higher_is_better=True, n_boot=N_BOOT)


def _span(change: tuple[float, float, float]) -> str:
    point, low, high = change
    text = pct(point)
    return text + f" [{pct(low)}, {pct(high)}]" if math.isfinite(low) else text


def sentence(changes: dict[str, tuple[float, float, float]]) -> str:
    """One sentence: whether adaptation contributes, from the changes with adaptation off
    (positive: the error or the time constant grows without it)."""
    parts = [f"{name} by {_span(c)}" for name, c in changes.items() if math.isfinite(c[0])]
    if not parts:
        return "Adaptation: not measured (no episodes with both the law and its ablation)."
    told = f"with adaptation off (b1 = 0) the {parts[0]}".replace(" by ", " changes by ", 1)
    if len(parts) > 1:
        told += " and the " + " and the ".join(parts[1:])
    bounds = [c for c in changes.values() if math.isfinite(c[1])]
    if not bounds:
        return f"Adaptation's contribution is not judged (one seed, no CI): {told}."
    if any(low > 0 for _, low, _ in bounds):
        return f"Adaptation contributes: {told}."
    if any(high < 0 for _, _, high in bounds):
        return (
            f"Adaptation does not measurably contribute (the law does better without it): {told}."
        )
    return f"Adaptation does not measurably contribute (every CI includes 0): {told}."


def ablation(episodes: pd.DataFrame, ctx: Context | None = None) -> Table:
    """Per agent and ablation label: the relative change of the tip RMS error and of the time
    constant 1/α when adaptation is switched off, with CIs, and the sentence it supports."""
    ctx = ctx or Context()
    ep = with_derived(episodes)
    names = agent_names(ep)
    shown_rows, numbers = [], []
    for agent in agents(ep):
        sub = of_agent(ep, agent)
        for off, on in labels.ablations(sub):
            changes: dict[str, tuple[float, float, float]] = {}
            shown: dict[str, Any] = {"Agent": names[agent]} if names else {}
            shown["Adaptation on / off"] = f"{on} / {off}"
            row: dict[str, Any] = {"agent": names.get(agent, ""), "on": on, "off": off}
            for what, key, tasks_only, reached in ABLATION:
                header = what[0].upper() + what[1:]
                a, b = paired(sub, key, on, off, tasks_only, reached)
                changes[what] = _change(a, b)
                shown[f"{header}: on / off"] = (
                    f"{number(float(stats.iqm(a)))} / {number(float(stats.iqm(b)))}"
                    if a.size else "–"
                )  # fmt: skip
                shown[f"{header}: change off vs on [95 % CI]"] = _span(changes[what])
                point, low, high = changes[what]
                row.update({f"{key}_change": point, f"{key}_change_ci_low": low,
                            f"{key}_change_ci_high": high, f"{key}_episodes": a.shape[1]
                            if a.ndim == 2 else 0})  # fmt: skip
            row["sentence"] = sentence(changes)
            shown["Adaptation"] = row["sentence"]
            shown_rows.append(shown)
            numbers.append(row)
    notes = [
        "Change off vs on: (IQM with adaptation off − IQM with it on) / IQM with it on, positive "
        "when switching adaptation off makes the tracking error or the time constant 1/α "
        "larger, i.e. when adaptation helps; 95 % stratified bootstrap CI over the runs within "
        "each episode. Tip RMS over the episodes both reached; time constant over the paper "
        "tasks where both decayed (α > 0). Adaptation contributes when a CI lies above 0.",
        statistics_note(*run_counts(ep)),
        *context_notes(ctx),
    ]
    return Table(
        "ablation",
        "Ablation: the proposed adaptive law with adaptation on and off",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )
