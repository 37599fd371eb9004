"""The report's one-screen summary (``tables/summary.{md,tex,csv}``): per agent, held-out success
with both controllers, the paper tasks reached, and the claim check's measured improvements and
verdicts. The README's results section is this table, copied from the report of a study.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp.report.performance import (
    PAPER_TASKS,
    agent_names,
    agents,
    iqm_cell,
    of_agent,
    pct,
    run_counts,
)
from armexp.report.tables import Context, Table


def _success(rows: pd.DataFrame, controller: str) -> tuple[str, dict[str, float]]:
    """Held-out success per eval run (seed), IQM [CI] over the runs, as a percentage."""
    held = rows[(rows.controller == controller) & rows.task.str.startswith("random_")]
    if held.empty:
        return "–", {"iqm": math.nan, "ci_low": math.nan, "ci_high": math.nan, "n": 0}
    per_run = held.groupby("eval_run").success.mean().to_numpy(dtype=float) * 100.0
    text, got = iqm_cell(per_run, 1)
    targets = int(held.groupby("eval_run").size().max())
    return f"{text} % of {targets}", got


def _claim_text(claims: pd.DataFrame, name: str, claim: str) -> tuple[str, str]:
    rows = claims[(claims.agent == name) & (claims.claim == claim)]
    if rows.empty:
        return "–", "–"
    r = rows.iloc[0]
    text = pct(float(r.get("improvement", math.nan)))
    low, high = float(r.get("ci_low", math.nan)), float(r.get("ci_high", math.nan))
    if math.isfinite(low):
        text += f" [{pct(low)}, {pct(high)}]"
    return text, str(r.verdict)


def summary(episodes: pd.DataFrame, claims: Table, ctx: Context | None = None) -> Table:
    """One row per agent (preset, aids, the gains it was evaluated with)."""
    ctx = ctx or Context()
    names = agent_names(episodes) or {a: "" for a in agents(episodes)}
    shown_rows, numbers = [], []
    for agent in agents(episodes):
        rows = of_agent(episodes, agent)
        name = names[agent]
        runs, seeds = run_counts(rows)
        tasks = rows[rows.task.isin(PAPER_TASKS) & (rows.controller == "adaptive")]
        ours, ours_n = _success(rows, "adaptive")
        pid, pid_n = _success(rows, "pid")
        conv, conv_verdict = _claim_text(claims.numbers, name, "faster convergence")
        acc, acc_verdict = _claim_text(claims.numbers, name, "better accuracy")
        shown: dict[str, Any] = {
            "Agent": name or str(agent),
            "Seeds": seeds,
            "Held-out success, proposed": ours,
            "Held-out success, PID": pid,
            "Paper tasks reached": f"{int(tasks.success.sum())}/{len(tasks)}",
            "Convergence vs PID [95 % CI]": conv,
            "verdict (≈ 10 %)": conv_verdict,
            "Tracking vs PID [95 % CI]": acc,
            "verdict (≈ 18 %)": acc_verdict,
        }
        shown_rows.append(shown)
        numbers.append(
            {"agent": agent, "seeds": seeds, "eval_runs": runs,
             "heldout_success_pct": ours_n["iqm"], "heldout_success_pct_ci_low": ours_n["ci_low"],
             "heldout_success_pct_ci_high": ours_n["ci_high"],
             "heldout_success_pid_pct": pid_n["iqm"],
             "tasks_reached": float(np.sum(tasks.success)), "tasks_run": len(tasks),
             "convergence_verdict": conv_verdict, "accuracy_verdict": acc_verdict,
             "eval_run_ids": " ".join(sorted(set(rows.eval_run)))}
        )  # fmt: skip
    notes = [
        "Held-out success: IQM [95 % CI] over the seeds of each seed's share of held-out targets "
        "reached. Convergence and tracking: the claim check's relative improvement over PID "
        "(positive: the proposed control is better) and its verdict.",
    ]
    if ctx.missing:
        notes.append(ctx.missing)
    return Table("summary", "Summary", pd.DataFrame(shown_rows), pd.DataFrame(numbers), notes,
                 caption=ctx.agent)  # fmt: skip
