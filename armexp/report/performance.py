"""Table III of the proposed control over the selected eval runs (seeds), and the helpers every
per-controller table shares (cells, agents, notes).

One eval run is one seed's policy evaluated once. Over several runs every cell is the
interquartile mean over the runs with its 95 % percentile bootstrap CI (`armexp.report.stats`,
`N_BOOT` resamples, fixed so a report is reproducible): in Table III the runs of one task are
resampled. With one run the cell is that run's value. A ratio against a zero, an unreached task
or a non-finite value is shown as "–" (docs/design.md §9).

Convergence (docs/design.md §8, the paper's Definition 1): after an initial reference offset the
eval run fits ‖e1(t)‖ ≤ ᾱ‖e1(0)‖e^(−αt) + α* and logs the decay rate α (``decay_rate``, 1/s),
the ultimate bound α* (``ultimate_bound``, rad), the settling time of ‖e1‖ and its ITAE, at the
small offset and (suffix ``_large``) at the large one. The claim check compares time constants
1/α (`with_derived`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp.report import labels, stats
from armexp.report.tables import Context, Table

#: Bootstrap resamples of every CI in the report.
N_BOOT = 2000
#: Table III as printed in the paper (target time s, target error cm, tracking error cm, max
#: torque N·m, convergence time s), shown beside ours.
PAPER_TABLE_III = {
    "a": (9.176, 0.025, 0.0006, 400.0, 0.01),
    "b": (9.92, 0.037, 0.0008, 360.0, 0.03),
    "c": (11.16, 0.029, 0.001, 400.0, 0.05),
    "d": (5.456, 0.039, 0.0002, 220.0, 0.009),
}
PAPER_TASKS = ("a", "b", "c", "d")
#: The paper's reach threshold (Table I), in cm.
PAPER_THRESHOLD_CM = 4.0
PLAIN_MISSING = (
    "The paper's plain SAC is not among the selected runs: add the eval runs of a plain preset "
    "(e.g. sac_paper) to report.eval_runs to show it beside the aided agent."
)


def number(value: float, digits: int = 3) -> str:
    if not math.isfinite(value):
        return "–"
    if abs(value) < 1e-2 and value != 0:
        return f"{value:.{digits}g}"
    return f"{value:.{digits}f}"


def iqm_cell(values: np.ndarray, digits: int = 3) -> tuple[str, dict[str, float]]:
    """ "IQM [low, high]" of one value per run (just the value for one run), and the numbers."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return "–", {"iqm": math.nan, "ci_low": math.nan, "ci_high": math.nan, "n": 0}
    if v.size == 1:
        return number(float(v[0]), digits), {
            "iqm": float(v[0]), "ci_low": math.nan, "ci_high": math.nan, "n": 1,
        }  # fmt: skip
    point, low, high = stats.iqm_ci(v, n_boot=N_BOOT)
    text = f"{number(point, digits)} [{number(low, digits)}, {number(high, digits)}]"
    return text, {"iqm": point, "ci_low": low, "ci_high": high, "n": int(v.size)}


def pct(x: float) -> str:
    return f"{100 * x:+.1f} %" if math.isfinite(x) else "–"


def _inverse(rate: pd.Series) -> pd.Series:
    """1/rate: inf where the rate is ≤ 0 (no decay), nan where it is nan."""
    r = rate.to_numpy(dtype=float)
    with np.errstate(divide="ignore"):
        out = np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), np.where(np.isnan(r), np.nan, np.inf))
    return pd.Series(out, index=rate.index)


def with_derived(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes with their label columns (`armexp.report.labels.ensure`) and the derived
    columns: ``max_torque`` (over joints), ``time_constant`` = 1/``decay_rate`` (s; inf for no
    decay) and ``ultimate_bound_mrad``, each also with suffix ``_large`` where logged."""
    out = labels.ensure(episodes).copy()
    taus = [c for c in out.columns if c.startswith("max_abs_tau_")]
    out["max_torque"] = out[taus].max(axis=1) if taus else np.nan
    for suffix in ("", "_large"):
        rate, bound = f"decay_rate{suffix}", f"ultimate_bound{suffix}"
        if rate in out.columns:
            out[f"time_constant{suffix}"] = _inverse(out[rate])
        if bound in out.columns:
            out[f"ultimate_bound{suffix}_mrad"] = out[bound].astype(float) * 1000.0
    return out


def has_values(episodes: pd.DataFrame, key: str) -> bool:
    """Whether any episode has a value of ``key`` (old eval runs lack the Definition-1 ones)."""
    return key in episodes.columns and bool(episodes[key].notna().any())


def _joints(episodes: pd.DataFrame) -> list[int]:
    return sorted(
        int(c.rsplit("_", 1)[1]) for c in episodes.columns if c.startswith("max_abs_tau_")
    )


def agents(episodes: pd.DataFrame) -> list[Any]:
    return list(dict.fromkeys(episodes["agent"])) if "agent" in episodes.columns else [None]


def of_agent(episodes: pd.DataFrame, agent: Any) -> pd.DataFrame:
    return episodes if agent is None else episodes[episodes["agent"] == agent]


def agent_names(episodes: pd.DataFrame) -> dict[Any, str]:
    """Short names of the agents when a table shows several (none: one agent, no column)."""
    labels = agents(episodes)
    if len(labels) <= 1:
        return {}
    short = {}
    for label in labels:
        first = of_agent(episodes, label).iloc[0]
        preset = str(first.get("agent_preset", label))
        name = f"{preset} (aided)" if bool(first.get("aided", False)) else f"{preset} (plain)"
        gains = str(first.get("gains", "") or "")
        short[label] = f"{name}, {gains}" if gains else name
    if len(set(short.values())) < len(short):
        return {label: str(label) for label in labels}
    return short


def agent_columns(rows: pd.DataFrame, agent: Any) -> dict[str, Any]:
    aided = bool(rows["aided"].iloc[0]) if "aided" in rows.columns and len(rows) else math.nan
    return {"agent": "" if agent is None else agent, "aided": aided}


def column(rows: pd.DataFrame, key: str) -> np.ndarray:
    return rows[key].to_numpy(dtype=float) if key in rows.columns else np.zeros(0)


def cell(rows: pd.DataFrame, key: str, numbers: dict[str, Any], digits: int = 3) -> str:
    """IQM [CI] of one column over the runs; the numbers go into ``numbers`` (the CSV row)."""
    text, got = iqm_cell(column(rows, key), digits)
    numbers.update({key: got["iqm"], f"{key}_ci_low": got["ci_low"],
                    f"{key}_ci_high": got["ci_high"], f"{key}_n": got["n"]})  # fmt: skip
    return text


def statistics_note(n_runs: int, n_seeds: int) -> str:
    if n_runs <= 1:
        return "One eval run: each cell is that run's value."
    return (
        f"IQM [95 % CI]: interquartile mean over each row's eval runs (one per seed; {n_runs} "
        f"runs, {n_seeds} seeds selected) with a percentile stratified bootstrap CI, {N_BOOT} "
        "resamples (Agarwal et al., NeurIPS 2021); a single run shows its value."
    )


def run_counts(ep: pd.DataFrame) -> tuple[int, int]:
    if "eval_run" not in ep.columns or not len(ep):
        return 0, 0
    seeds = ep["seed"].nunique() if "seed" in ep.columns else ep.eval_run.nunique()
    return int(ep.eval_run.nunique()), int(seeds)


def convergence_note(ctx: Context) -> str:
    offset = f" of {ctx.initial_offset} on every joint" if ctx.initial_offset else ""
    return (
        "‡ Convergence as the paper defines it (Definition 1): after an initial reference "
        f"offset{offset}, small enough not to saturate, the fit ‖e1(t)‖ ≤ ᾱ‖e1(0)‖e^(−αt) + α* "
        "gives the decay rate α (1/s, higher is faster; its time constant is 1/α) and the "
        "ultimate bound α*; the settling time is the first time after which ‖e1‖ stays within "
        "max(2 % of the offset, a fixed tolerance); – : not logged, or never settled. The paper "
        "calls its last column “optimization time” (0.009–0.05 s); its row shows it under "
        "settling time."
    )


def subtraction_note() -> str:
    return (
        "Run subtraction: eval runs made before the Definition-1 measures logged the 2 % "
        "settling time of (e1 with the offset − e1 without it), a linear subtraction across "
        "runs that may saturate; shown only for those runs and not used by the claim check."
    )


def units_note() -> str:
    rows = PAPER_TABLE_III.values()
    errors, tracking = [v[1] for v in rows], [v[2] for v in rows]
    lo, hi = min(errors), max(errors)
    t_lo, t_hi = min(tracking), max(tracking)
    return (
        "† Paper: its Table III (proposed control only), values and units as printed. Its "
        f"target-error column is labelled cm, but {lo:g}–{hi:g} cm ({lo * 10:g}–{hi * 10:g} mm) "
        f"is far below anything its {PAPER_THRESHOLD_CM:g} cm reach threshold would stop at; "
        f"read as metres ({lo * 100:g}–{hi * 100:g} cm) the values sit just under the threshold, "
        f"where the motion stops. Its tracking column ({t_lo:g}–{t_hi:g} “cm”) fits only as "
        f"metres too ({t_lo * 100:g}–{t_hi * 100:g} cm). Our errors are in cm."
    )


def cannot_fail_note(ctx: Context) -> str:
    """Item 7 of the reproduction: the columns that hold by construction."""
    threshold = ctx.reach_threshold * 100.0
    return (
        "§ Columns that cannot fail. Target error: the episode ends when the tip is within "
        f"{threshold:g} cm of the target, checked once per {ctx.action_period * 1000:g} ms "
        f"action, so a reached episode's final error is {threshold:g} cm minus at most one "
        "action's travel of the tip: it measures the threshold, not the controller. Target "
        "time: tasks (a)–(d) were placed so that the paper's target times are matched, so "
        "agreement with its column is by construction."
    )


def context_notes(ctx: Context) -> list[str]:
    notes = []
    if ctx.missing:
        notes.append(ctx.missing)
    if ctx.plain_missing:
        notes.append(PLAIN_MISSING)
    return notes


def proposed_labels(episodes: pd.DataFrame) -> list[str]:
    """The labels with role ``proposed`` (episodes with label columns), in table order."""
    return [
        label for label in labels.ordered(episodes)
        if labels.info(episodes, label).get("role") == "proposed"
    ]  # fmt: skip


#: Table III's convergence columns: (header, key, digits).
CONVERGENCE_COLUMNS = (
    ("Decay rate α (1/s)‡", "decay_rate", 3),
    ("Ultimate bound α* (mrad)‡", "ultimate_bound_mrad", 3),
    ("Settling time (s)‡", "settling_time", 3),
)


def _paper_row(
    task: str, names: dict[Any, str], columns: list[str]
) -> tuple[dict[str, Any], dict[str, Any]]:
    target_time, error, tracking, max_torque, conv = PAPER_TABLE_III[task]
    shown: dict[str, Any] = {"Task": f"({task})", "Control": "paper"}
    if names:
        shown["Agent"] = "–"
    shown.update({"Reached": "–", "Target time (s)§": f"{target_time:g}",
                  "Target error (cm)§": f"{error:g} cm†",
                  "Tracking error (cm)": f"{tracking:g} cm†",
                  columns[0]: f"{max_torque:g} (either joint)"})  # fmt: skip
    for header in columns[1:]:
        shown[header] = "–"
    shown["Settling time (s)‡"] = f"{conv:g} (optimization time)"
    number_row = {"task": task, "controller": "paper", "target_time": target_time,
                  "final_error_cm": error, "tip_rms_cm": tracking, "max_torque": max_torque,
                  "settling_time": conv,
                  "note": "as printed; the target-error and tracking columns are labelled cm "
                  "but read as metres; settling time: the paper's optimization time"}  # fmt: skip
    return shown, number_row


def table_three(episodes: pd.DataFrame, ctx: Context | None = None) -> Table:
    """Per paper task: the proposed control's Table III quantities (IQM [95 % CI] over the
    selected eval runs when there are several) with the Definition-1 convergence, and the
    paper's row as printed; per agent when the selection holds several. The baselines are in
    the controller comparison (`armexp.report.comparison`)."""
    ctx = ctx or Context()
    ep = with_derived(episodes)
    ep = ep[ep.task.isin(PAPER_TASKS) & (ep.role == "proposed")]
    joints = _joints(ep)
    at_limit = has_values(ep, "time_at_limit")
    old = has_values(ep, "convergence_time")
    names = agent_names(ep)
    torque = f"Max torque {' / '.join(f'τ{j}' for j in joints)} (N·m)"
    extra = [torque] + (["Time at limit (s)"] if at_limit else [])
    extra += [h for h, _, _ in CONVERGENCE_COLUMNS] + (["Run subtraction (s)"] if old else [])
    shown_rows, numbers = [], []
    for task in sorted(ep.task.unique()):
        for agent in agents(ep):
            for label in proposed_labels(of_agent(ep, agent)):
                rows = of_agent(ep[(ep.task == task) & (ep.controller == label)], agent)
                if rows.empty:
                    continue
                shown: dict[str, Any] = {"Task": f"({task})", "Control": "proposed"}
                if names:
                    shown["Agent"] = names[agent]
                shown["Reached"] = f"{int(rows.success.sum())}/{len(rows)}"
                row: dict[str, Any] = {"task": task, "controller": label,
                                       **agent_columns(rows, agent), "runs": len(rows),
                                       "success_rate": rows.success.mean()}  # fmt: skip
                shown["Target time (s)§"] = cell(rows, "target_time", row)
                shown["Target error (cm)§"] = cell(rows, "final_error_cm", row)
                shown["Tracking error (cm)"] = cell(rows, "tip_rms_cm", row)
                shown[torque] = " / ".join(cell(rows, f"max_abs_tau_{j}", row, 1) for j in joints)
                cell(rows, "max_torque", row, 1)
                if at_limit:
                    shown["Time at limit (s)"] = cell(rows, "time_at_limit", row)
                for header, key, digits in CONVERGENCE_COLUMNS:
                    shown[header] = cell(rows, key, row, digits)
                if old:
                    shown["Run subtraction (s)"] = cell(rows, "convergence_time", row)
                shown_rows.append(shown)
                numbers.append(row)
        if task in PAPER_TABLE_III:
            paper_shown, paper_numbers = _paper_row(task, names, extra)
            shown_rows.append(paper_shown)
            numbers.append(paper_numbers)
    threshold = ctx.reach_threshold * 100.0
    limits = " Time at limit: seconds with a joint torque at its limit." if at_limit else ""
    if ctx.torque_limit:
        limits += f" Torque limit: {ctx.torque_limit} (robot.torque_limit)."
    notes = [
        f"Reached: episodes whose tip came within {threshold:g} cm of the target. Target time: "
        f"first time the tip error < {threshold:g} cm (reached episodes only; – : not reached). "
        "Target error: tip-to-target distance at the episode's end. Tracking error: RMS distance "
        "between the tip at q and at q_d. Max torque: the largest |τ| over the episode, per "
        f"joint.{limits}",
        cannot_fail_note(ctx),
        convergence_note(ctx),
        *([subtraction_note()] if old else []),
        units_note(),
        statistics_note(*run_counts(ep)),
        "The baselines and the ablation: the controller comparison table.",
        *context_notes(ctx),
    ]
    return Table(
        "table3_performance",
        "Table III: performance of the proposed control",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )
