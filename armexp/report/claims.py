"""The claim check of docs/design.md §9: the paper's claims against PID, with robust statistics.

The paper claims about 10 % faster convergence and 18 % better accuracy than a PID. For each
claim the episodes both controllers ran and reached in every selected eval run form a score
matrix, one row per eval run (seed) and one column per episode (task or held-out target; the
strata). The measured improvement is (IQM_PID − IQM_proposed) / IQM_PID of the metric (lower is
better for both), with a 95 % stratified bootstrap CI over the runs within each episode
(`armexp.report.stats`). The probability of improvement is P(proposed < PID) per episode,
averaged. The verdict is `armexp.report.stats.verdict` against the claimed size; with fewer than
two seeds there is no spread between seeds to measure, so the table shows the point values and
says why it gives no verdict.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp.report import stats
from armexp.report.performance import N_BOOT, PAPER_TASKS, agent_names, run_counts, with_pid
from armexp.report.tables import Context, Table

#: (claim, metric column, what it measures, claimed relative improvement, paper tasks only).
CLAIMS = (
    ("faster convergence", "convergence_time", "convergence time (s)", 0.10, True),
    ("better accuracy", "tip_rms_cm", "tip tracking error (cm)", 0.18, False),
)
#: Fewer distinct seeds than this: the claim is measured but no verdict is given.
MIN_SEEDS = 2


def _matrices(rows: pd.DataFrame, key: str, tasks_only: bool) -> tuple[np.ndarray, np.ndarray]:
    """(proposed, PID) score matrices (runs × episodes) over the episodes both controllers
    reached with a finite, positive value in every run."""
    if tasks_only:
        rows = rows[rows.task.isin(PAPER_TASKS)]
    if key not in rows.columns or rows.empty:
        return np.zeros((0, 0)), np.zeros((0, 0))
    table = rows.pivot_table(
        index="eval_run", columns=["task", "controller"], values=[key, "success"], aggfunc="first"
    )
    keep = []
    for task in sorted({t for t, _ in table[key].columns}):
        ok = True
        for controller in ("adaptive", "pid"):
            if (task, controller) not in table[key].columns:
                ok = False
                break
            value = table[key][(task, controller)].to_numpy(dtype=float)
            success = table["success"][(task, controller)].to_numpy(dtype=float)
            ok &= bool(np.all(np.isfinite(value) & (value > 0) & (success > 0)))
        if ok:
            keep.append(task)
    ours = np.array([table[key][(t, "adaptive")].to_numpy(dtype=float) for t in keep]).T
    pid = np.array([table[key][(t, "pid")].to_numpy(dtype=float) for t in keep]).T
    return ours.reshape(len(table), len(keep)), pid.reshape(len(table), len(keep))


def _check(ours: np.ndarray, pid: np.ndarray, claimed: float, seeds: int) -> dict[str, Any]:
    runs, episodes = ours.shape
    if episodes == 0 or runs == 0:
        judged = "inconclusive" if seeds >= MIN_SEEDS else f"none (needs ≥ {MIN_SEEDS} seeds)"
        return {"runs": runs, "episodes": 0, "seeds": seeds, "verdict": judged}
    out: dict[str, Any] = {
        "runs": runs,
        "episodes": episodes,
        "seeds": seeds,
        "iqm_proposed": float(stats.iqm(ours)),
        "iqm_pid": float(stats.iqm(pid)),
        "prob_improvement": stats.probability_of_improvement(ours, pid, higher_is_better=False),
    }
    if seeds < MIN_SEEDS or runs < 2:
        base = out["iqm_pid"]
        point = (base - out["iqm_proposed"]) / base if base > 0 else math.nan
        return {
            **out,
            "improvement": point,
            "ci_low": math.nan,
            "ci_high": math.nan,
            "prob_ci_low": math.nan,
            "prob_ci_high": math.nan,
            "verdict": f"none (needs ≥ {MIN_SEEDS} seeds)",
        }
    point, low, high = stats.relative_improvement_ci(ours, pid, n_boot=N_BOOT)
    p, p_low, p_high = stats.probability_of_improvement_ci(
        ours, pid, higher_is_better=False, n_boot=N_BOOT
    )
    return {
        **out,
        "improvement": float(point),
        "ci_low": float(low),
        "ci_high": float(high),
        "prob_improvement": float(p),
        "prob_ci_low": float(p_low),
        "prob_ci_high": float(p_high),
        "verdict": stats.verdict(low, high, claimed),
    }


def _pct(x: float) -> str:
    return f"{100 * x:+.1f} %" if math.isfinite(x) else "–"


def claim_check(episodes: pd.DataFrame, ctx: Context | None = None) -> Table:
    """One row per claim (and per agent when several presets are selected)."""
    ctx = ctx or Context()
    names = agent_names(episodes)
    shown_rows, numbers = [], []
    for agent, sub in with_pid(episodes):
        _, seeds = run_counts(sub)
        for claim, key, metric, claimed, tasks_only in CLAIMS:
            result = _check(*_matrices(sub, key, tasks_only), claimed, seeds)
            shown: dict[str, Any] = {"Claim": f"{claim} (paper: ≈ {100 * claimed:.0f} %)"}
            if names:
                shown["Agent"] = names[agent]
            shown["Metric"] = metric
            shown["Runs × episodes"] = f"{result['runs']} × {result['episodes']}"
            if result["episodes"]:
                shown["IQM proposed / PID"] = (
                    f"{result['iqm_proposed']:.4g} / {result['iqm_pid']:.4g}"
                )
                shown["Improvement [95 % CI]"] = _pct(result["improvement"])
                if math.isfinite(result["ci_low"]):
                    shown["Improvement [95 % CI]"] += (
                        f" [{_pct(result['ci_low'])}, {_pct(result['ci_high'])}]"
                    )
                prob = f"{result['prob_improvement']:.2f}"
                if math.isfinite(result["prob_ci_low"]):
                    prob += f" [{result['prob_ci_low']:.2f}, {result['prob_ci_high']:.2f}]"
                shown["P(improvement)"] = prob
            else:
                shown["IQM proposed / PID"] = "–"
                shown["Improvement [95 % CI]"] = "–"
                shown["P(improvement)"] = "–"
            shown["Verdict"] = result["verdict"]
            shown_rows.append(shown)
            numbers.append(
                {
                    "claim": claim,
                    "metric": key,
                    "claimed": claimed,
                    "agent": names.get(agent, ""),
                    **result,
                }
            )
    notes = [
        "Improvement: (IQM of PID − IQM of the proposed control) / IQM of PID over the episodes "
        "both controllers reached in every selected eval run, positive when the proposed "
        "control is better; 95 % stratified bootstrap CI over the runs (seeds) within each "
        f"episode ({N_BOOT} resamples). P(improvement): probability that "
        "the proposed control's value is the lower one in an episode (Mann–Whitney), with its "
        "CI over runs. Verdict: confirmed (CI above the claimed size), direction only (CI above "
        "0, not all above the claim), refuted (CI below 0), inconclusive (otherwise). "
        "Agarwal et al., NeurIPS 2021.",
    ]
    few = sorted({r["seeds"] for r in numbers if r["seeds"] < MIN_SEEDS})
    if few:
        notes.append(
            f"No verdict where fewer than {MIN_SEEDS} seeds were selected ({few[0]} here): a "
            "claim is settled by the spread between seeds, which one seed cannot show. Select "
            "several seeds' eval runs (e.g. experiment=reproduce)."
        )
    if ctx.missing:
        notes.append(ctx.missing)
    return Table(
        "claim_check",
        "Claim check: the paper's claims against PID",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )
