"""The claim check of DESIGN §9: the paper's claims against PID, with robust statistics.

The paper claims about 10 % faster convergence and 18 % better accuracy than a PID. For each
claim the episodes both controllers ran and reached in every selected eval run form a score
matrix, one row per eval run (seed) and one column per episode (task or held-out target; the
strata). The measured improvement is (IQM_PID − IQM_proposed) / IQM_PID of the metric (lower is
better for both), with a 95 % stratified bootstrap CI over the runs within each episode
(`armexp.report.stats`); with a single run the episodes themselves are resampled. The
probability of improvement is P(proposed < PID) per episode, averaged. The verdict is
`armexp.report.stats.verdict` against the claimed size.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp.report import stats
from armexp.report.tables import PAPER_TASKS, Context, Table, _agent_names, _agents, _of_agent

#: (claim, metric column, what it measures, claimed relative improvement, paper tasks only).
CLAIMS = (
    ("faster convergence", "convergence_time", "convergence time (s)", 0.10, True),
    ("better accuracy", "tip_rms_cm", "tip tracking error (cm)", 0.18, False),
)
N_BOOT = 2000


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


def _check(ours: np.ndarray, pid: np.ndarray, claimed: float) -> dict[str, Any]:
    runs, episodes = ours.shape
    if episodes == 0 or runs == 0:
        return {"runs": runs, "episodes": 0, "verdict": "inconclusive"}
    # With one run there is nothing to resample across seeds: resample the episodes instead.
    a, b = (ours, pid) if runs > 1 else (ours.T, pid.T)
    point, low, high = stats.relative_improvement_ci(a, b, n_boot=N_BOOT)
    if runs > 1:
        p, p_low, p_high = stats.probability_of_improvement_ci(
            ours, pid, higher_is_better=False, n_boot=N_BOOT
        )
    else:  # one run per episode: the share of episodes where the proposed control is better
        p = stats.probability_of_improvement(ours, pid, higher_is_better=False)
        p_low = p_high = math.nan
    return {
        "runs": runs,
        "episodes": episodes,
        "iqm_proposed": float(stats.iqm(ours)),
        "iqm_pid": float(stats.iqm(pid)),
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
    names = _agent_names(episodes)
    shown_rows, numbers = [], []
    for agent in _agents(episodes):
        sub = _of_agent(episodes, agent)
        for claim, key, metric, claimed, tasks_only in CLAIMS:
            result = _check(*_matrices(sub, key, tasks_only), claimed)
            shown: dict[str, Any] = {"Claim": f"{claim} (paper: ≈ {100 * claimed:.0f} %)"}
            if names:
                shown["Agent"] = names[agent]
            shown["Metric"] = metric
            shown["Runs × episodes"] = f"{result['runs']} × {result['episodes']}"
            if result["episodes"]:
                shown["IQM proposed / PID"] = (
                    f"{result['iqm_proposed']:.4g} / {result['iqm_pid']:.4g}"
                )
                shown["Improvement [95 % CI]"] = (
                    f"{_pct(result['improvement'])} "
                    f"[{_pct(result['ci_low'])}, {_pct(result['ci_high'])}]"
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
                {"claim": claim, "metric": key, "claimed": claimed, "agent": names.get(agent, ""),
                 **result}
            )  # fmt: skip
    notes = [
        "Improvement: (IQM of PID − IQM of the proposed control) / IQM of PID over the episodes "
        "both controllers reached in every selected eval run, positive when the proposed "
        "control is better; 95 % stratified bootstrap CI over the runs (seeds) within each "
        "episode, or over the episodes when there is one run. P(improvement): probability that "
        "the proposed control's value is the lower one in an episode (Mann–Whitney), with its "
        "CI over runs. Verdict: confirmed (CI above the claimed size), direction only (CI above "
        "0, not all above the claim), refuted (CI below 0), inconclusive (otherwise). "
        "Agarwal et al., NeurIPS 2021.",
    ]
    if any(r["runs"] == 1 for r in numbers):
        notes.append(
            "One eval run: the CI covers the episodes of one seed only, not the spread between "
            "seeds; select several seeds' eval runs to settle a claim."
        )
    return Table(
        "claim_check",
        "Claim check: the paper's claims against PID",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )
