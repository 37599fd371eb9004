"""The report's one-screen summary (``tables/summary.{md,tex,csv}``): per agent and baseline,
held-out success of the proposed control and of the baseline, the paper tasks reached, and the
claim check's measured improvements and two-sided verdicts; under it, per agent, whether
adaptation contributes (the ablation). The README's results section is this table, copied from
the report of a study (``scripts/readme_results.py``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp import paper
from armexp.report import labels
from armexp.report.claims import CLAIMS
from armexp.report.comparison import held_out_success
from armexp.report.episodes import (
    agent_names,
    agents,
    of_agent,
    proposed_labels,
    run_counts,
    with_derived,
)
from armexp.report.formatting import Context, Table, pct


def _claim_text(claims: pd.DataFrame, name: str, claim: str, baseline: str) -> tuple[str, str]:
    if claims.empty or "baseline" not in claims.columns:
        return "–", "–"
    rows = claims[(claims.agent == name) & (claims.claim == claim) & (claims.baseline == baseline)]
    if rows.empty:
        return "–", "–"
    r = rows.iloc[0]
    text = pct(float(r.get("improvement", math.nan)))
    low, high = float(r.get("ci_low", math.nan)), float(r.get("ci_high", math.nan))
    if math.isfinite(low):
        text += f" [{pct(low)}, {pct(high)}]"
    return text, str(r.verdict)


def _ablation_sentences(ablation: Table | None) -> dict[str, str]:
    if ablation is None or ablation.numbers.empty:
        return {}
    return {str(r.agent): str(r.sentence) for r in ablation.numbers.itertuples()}


def summary(
    episodes: pd.DataFrame, claims: Table, ablation: Table | None = None, ctx: Context | None = None
) -> Table:
    """One row per agent (preset, aids, the gains it was evaluated with) and baseline; an agent
    evaluated without baselines has one row with its own success only."""
    ctx = ctx or Context()
    ep = with_derived(episodes)
    names = agent_names(ep) or {a: "" for a in agents(ep)}
    adaptation = _ablation_sentences(ablation)
    (conv, acc) = CLAIMS
    shown_rows, numbers = [], []
    for agent in agents(ep):
        rows = of_agent(ep, agent)
        name = names[agent]
        runs, seeds = run_counts(rows)
        pairs = labels.comparisons(rows) or [
            ("", label) for label in proposed_labels(rows)[:1]
        ]  # fmt: skip
        for baseline, proposed in pairs:
            tasks = rows[rows.task.isin(paper.TASKS) & (rows.controller == proposed)]
            ours, ours_n = held_out_success(rows, proposed)
            base, base_n = held_out_success(rows, baseline) if baseline else ("–", {})
            conv_text, conv_verdict = _claim_text(claims.numbers, name, conv.name, baseline)
            acc_text, acc_verdict = _claim_text(claims.numbers, name, acc.name, baseline)
            shown: dict[str, Any] = {
                "Agent": name or str(agent),
                "Seeds": seeds,
                "Proposed": labels.describe(rows, proposed),
                "Baseline": labels.describe(rows, baseline) if baseline else "–",
                "Held-out success, proposed": ours,
                "Held-out success, baseline": base,
                "Paper tasks reached": f"{int(tasks.success.sum())}/{len(tasks)}",
                "Convergence vs baseline [95 % CI]": conv_text,
                f"verdict (≈ {100 * conv.claimed:.0f} %)": conv_verdict,
                "Tracking vs baseline [95 % CI]": acc_text,
                f"verdict (≈ {100 * acc.claimed:.0f} %)": acc_verdict,
            }
            shown_rows.append(shown)
            numbers.append(
                {"agent": name or str(agent), "seeds": seeds, "eval_runs": runs,
                 "proposed": proposed, "baseline": baseline,
                 "heldout_success_pct": ours_n["iqm"],
                 "heldout_success_pct_ci_low": ours_n["ci_low"],
                 "heldout_success_pct_ci_high": ours_n["ci_high"],
                 "heldout_success_baseline_pct": base_n.get("iqm", math.nan),
                 "tasks_reached": float(np.sum(tasks.success)), "tasks_run": len(tasks),
                 "convergence_verdict": conv_verdict, "accuracy_verdict": acc_verdict,
                 "adaptation": adaptation.get(name, ""),
                 "eval_run_ids": " ".join(sorted(set(rows.eval_run)))}
            )  # fmt: skip
    notes = [
        "Held-out success: IQM [95 % CI] over the seeds of each seed's share of held-out targets "
        "reached. Convergence (time constant 1/α) and tracking: the claim check's relative "
        "improvement over the baseline (positive: the proposed control is better) and its "
        "two-sided verdict: consistent, larger than claimed, smaller than claimed, refuted or "
        "inconclusive (the claim check's notes say what each means). Proposed and baseline: "
        "each label's controller and the criterion and horizon it was tuned under.",
    ]
    for agent in agents(ep):
        sentence = adaptation.get(names[agent])
        if sentence:
            notes.append(f"{names[agent] + ': ' if names[agent] else ''}{sentence}")
    if ctx.missing:
        notes.append(ctx.missing)
    return Table("summary", "Summary", pd.DataFrame(shown_rows), pd.DataFrame(numbers), notes,
                 caption=ctx.agent)  # fmt: skip
