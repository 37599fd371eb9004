"""The claim check of docs/design.md §9: the paper's claims against every baseline, with robust
statistics and two-sided verdicts.

The paper claims about 10 % faster convergence and 18 % better accuracy than a PID. Each
baseline an eval run ran is compared with the proposed label its ``controllers.yaml`` names
(``compare_with``: the proposed law tuned under the baseline's criterion; old runs: ``adaptive``
against ``pid_gaing``). Convergence is the time constant 1/α of the Definition-1 decay rate at
the small offset on the paper tasks (lower is faster); accuracy is the tip tracking error over
the episodes both controllers reached. The episodes with a finite, positive value for both in
every selected eval run form a score matrix, one row per eval run (seed) and one column per
episode (the strata). The measured improvement is (IQM_baseline − IQM_proposed) / IQM_baseline,
with a 95 % stratified bootstrap CI over the runs within each episode (`armexp.report.stats`);
the probability of improvement is P(proposed < baseline) per episode, averaged. The verdict is
`armexp.report.stats.verdict` against the claimed size; with fewer than two seeds there is no
spread between seeds to measure, so the table shows the point values and says why it gives no
verdict. The CI includes tuning variation only where the tuner seeds differ between the runs.
"""

from __future__ import annotations

import math
from typing import Any, NamedTuple

import numpy as np
import pandas as pd

from armexp import paper
from armexp.report import labels, stats
from armexp.report.comparison import paired
from armexp.report.episodes import (
    agent_names,
    agents,
    has_values,
    of_agent,
    run_counts,
    with_derived,
)
from armexp.report.formatting import N_BOOT, Context, Table, pct


class Claim(NamedTuple):
    name: str
    key: str
    metric: str
    claimed: float
    tasks_only: bool
    reached: bool


CLAIMS = (
    Claim("faster convergence", "time_constant", "time constant 1/α, small offset (s)",
          paper.FASTER_CONVERGENCE, True, False),
    Claim("better accuracy", "tip_rms_cm", "tip tracking error (cm)", paper.BETTER_ACCURACY,
          False, True),
)  # fmt: skip
#: Fewer distinct seeds than this: the claim is measured but no verdict is given.
MIN_SEEDS = 2
#: The verdict of a claim that the eval runs cannot measure (old runs: no decay rate).
NOT_MEASURED = "–"


def _check(ours: np.ndarray, base: np.ndarray, claimed: float, seeds: int) -> dict[str, Any]:
    runs, episodes = ours.shape
    if episodes == 0 or runs == 0:
        judged = "inconclusive" if seeds >= MIN_SEEDS else f"none (needs ≥ {MIN_SEEDS} seeds)"
        return {"runs": runs, "episodes": 0, "seeds": seeds, "verdict": judged}
    out: dict[str, Any] = {
        "runs": runs,
        "episodes": episodes,
        "seeds": seeds,
        "iqm_proposed": float(stats.iqm(ours)),
        "iqm_baseline": float(stats.iqm(base)),
        "prob_improvement": stats.probability_of_improvement(ours, base, higher_is_better=False),
    }
    if seeds < MIN_SEEDS or runs < 2:
        b = out["iqm_baseline"]
        point = (b - out["iqm_proposed"]) / b if b > 0 else math.nan
        return {**out, "improvement": point, "ci_low": math.nan, "ci_high": math.nan,
                "prob_ci_low": math.nan, "prob_ci_high": math.nan,
                "verdict": f"none (needs ≥ {MIN_SEEDS} seeds)"}  # fmt: skip
    point, low, high = stats.relative_improvement_ci(ours, base, n_boot=N_BOOT)
    p, p_low, p_high = stats.probability_of_improvement_ci(
        ours, base, higher_is_better=False, n_boot=N_BOOT
    )
    return {**out, "improvement": float(point), "ci_low": float(low), "ci_high": float(high),
            "prob_improvement": float(p), "prob_ci_low": float(p_low),
            "prob_ci_high": float(p_high),
            "verdict": stats.verdict(low, high, claimed)}  # fmt: skip


def tuning_in_ci(rows: pd.DataFrame, label: str) -> str:
    """What the spread over a label's eval runs covers: ``policy and tuning`` where its tune
    runs' seeds differ between the runs (and gave different gains), else ``policy only``, with
    the reason."""
    own = rows[rows.controller == label].drop_duplicates("eval_run")
    runs = len(own)
    if not runs or str(own.criterion.iloc[0]) == labels.CONFIGURED:
        return "policy only (configured gains)"
    if runs < 2:
        return "one run"
    seeds = {s for s in own.tuner_seed if isinstance(s, float | int) and math.isfinite(s)}
    if len(seeds) < 2:
        return (
            "policy only (tuner seed not logged)"
            if not seeds
            else f"policy only (tuner seed {int(next(iter(seeds)))} at every run)"
        )
    gains = {g for g in own.gains_text if isinstance(g, str) and g}
    if len(gains) == 1:
        return f"policy only (identical gains at all {len(seeds)} tuner seeds)"
    return f"policy and tuning ({len(seeds)} tuner seeds)"


def _row(sub: pd.DataFrame, claim: Claim, baseline: str, proposed: str) -> dict[str, Any]:
    """The numbers of one claim against one baseline."""
    _, seeds = run_counts(sub)
    if claim.tasks_only and not has_values(
        sub[sub.controller.isin([baseline, proposed])], claim.key
    ):
        result: dict[str, Any] = {"runs": 0, "episodes": 0, "seeds": seeds, "verdict": NOT_MEASURED}
    else:
        ours, base = paired(sub, claim.key, proposed, baseline, claim.tasks_only, claim.reached)
        result = _check(ours, base, claim.claimed, seeds)
    base_info, ours_info = labels.info(sub, baseline), labels.info(sub, proposed)
    return {
        "claim": claim.name,
        "metric": claim.key,
        "claimed": claim.claimed,
        "baseline": baseline,
        "baseline_controller": base_info["controller_name"],
        "criterion": base_info["criterion"],
        "horizon": base_info["horizon"],
        "proposed": proposed,
        "proposed_criterion": ours_info["criterion"],
        "ci_covers": "; ".join(
            dict.fromkeys(f"{lab}: {tuning_in_ci(sub, lab)}" for lab in (proposed, baseline))
        ),
        **result,
    }


def _shown(row: dict[str, Any], agent: str | None, sub: pd.DataFrame) -> dict[str, Any]:
    claim = next(c for c in CLAIMS if c.name == row["claim"])
    shown: dict[str, Any] = {"Claim": f"{claim.name} (paper: ≈ {100 * claim.claimed:.0f} %)"}
    if agent is not None:
        shown["Agent"] = agent
    shown["Baseline"] = labels.describe(sub, row["baseline"])
    shown["Proposed"] = labels.describe(sub, row["proposed"])
    shown["Metric"] = claim.metric
    shown["Runs × episodes"] = f"{row['runs']} × {row['episodes']}"
    if row["episodes"]:
        shown["IQM proposed / baseline"] = f"{row['iqm_proposed']:.4g} / {row['iqm_baseline']:.4g}"
        text = pct(row["improvement"])
        if math.isfinite(row["ci_low"]):
            text += f" [{pct(row['ci_low'])}, {pct(row['ci_high'])}]"
        shown["Improvement [95 % CI]"] = text
        prob = f"{row['prob_improvement']:.2f}"
        if math.isfinite(row["prob_ci_low"]):
            prob += f" [{row['prob_ci_low']:.2f}, {row['prob_ci_high']:.2f}]"
        shown["P(improvement)"] = prob
    else:
        shown["IQM proposed / baseline"] = "–"
        shown["Improvement [95 % CI]"] = "–"
        shown["P(improvement)"] = "–"
    shown["CI covers"] = row["ci_covers"]
    shown["Verdict"] = row["verdict"]
    return shown


def claim_check(episodes: pd.DataFrame, ctx: Context | None = None) -> Table:
    """One row per claim and baseline (and agent when several are selected)."""
    ctx = ctx or Context()
    ep = with_derived(episodes)
    names = agent_names(ep)
    shown_rows, numbers = [], []
    for agent in agents(ep):
        sub = of_agent(ep, agent)
        for baseline, proposed in labels.comparisons(sub):
            for claim in CLAIMS:
                row = {"agent": names.get(agent, ""), **_row(sub, claim, baseline, proposed)}
                shown_rows.append(_shown(row, names.get(agent) if names else None, sub))
                numbers.append(row)
    notes = [
        "Improvement: (IQM of the baseline − IQM of the proposed control) / IQM of the "
        "baseline over the episodes both ran (accuracy: both reached) with a finite value in "
        "every selected eval run, positive when the proposed control is better; 95 % "
        f"stratified bootstrap CI over the runs (seeds) within each episode ({N_BOOT} "
        "resamples). P(improvement): probability that the proposed control's value is the lower "
        "one in an episode (Mann–Whitney), with its CI over runs. Agarwal et al., NeurIPS 2021.",
        "Verdict (two-sided, against the paper's claimed size): consistent (the CI lies above 0 "
        "and covers the claimed size), larger than claimed (the CI lies above it), smaller than "
        "claimed (the CI lies between 0 and it), refuted (the CI lies below 0: the baseline is "
        "better), inconclusive (the CI contains 0).",
        "Convergence: the time constant 1/α of the Definition-1 decay rate α after the small "
        "initial offset, on the paper tasks (lower is faster). Each row names the baseline's "
        "controller and the criterion and horizon both sides were tuned under.",
        "CI covers: the CI is over seeds; it includes the tuning's variation only where the "
        "tune runs' tuner.seed differs between seeds (and the tuner returned different gains); "
        "otherwise it covers the policy's variation only.",
    ]
    if any(r["criterion"] == "gaing" for r in numbers):
        notes.append(labels.GAING_NOTE)
    if any(r["verdict"] == NOT_MEASURED for r in numbers):
        notes.append(
            f"{NOT_MEASURED} (convergence): eval runs made before the Definition-1 measures log "
            "no decay rate; their run-subtraction convergence time is not a rate and is not "
            "judged."
        )
    few = sorted({r["seeds"] for r in numbers if r["seeds"] < MIN_SEEDS})
    if few:
        notes.append(
            f"No verdict where fewer than {MIN_SEEDS} seeds were selected ({few[0]} here): a "
            "claim is settled by the spread between seeds, which one seed cannot show. Select "
            "several seeds' eval runs (e.g. experiment=reproduce)."
        )
    if not numbers:
        notes.append(
            "No baseline among the selected eval runs: nothing to check the claims against."
        )
    if ctx.missing:
        notes.append(ctx.missing)
    return Table(
        "claim_check",
        "Claim check: the paper's claims against each baseline",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
        caption=ctx.agent,
    )
