"""The claim check (docs/design.md §9) on episode tables with known outcomes."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from armexp.report.claims import claim_check

TASKS = ("a", "b", "c", "d")


def _episodes(
    runs: int, conv: tuple[float, float], tracking: tuple[float, float], noise: float = 0.02
) -> pd.DataFrame:
    """Episodes of ``runs`` eval runs: the paper tasks and 20 held-out targets per controller,
    with (proposed, PID) convergence and tracking around the given values."""
    rng = np.random.default_rng(0)
    rows = []
    for r in range(runs):
        for task in (*TASKS, *(f"random_{i:03d}" for i in range(20))):
            for k, controller in enumerate(("adaptive", "pid")):
                rows.append(
                    {"eval_run": f"run{r}", "controller": controller, "task": task,
                     "success": 1.0, "agent": "sac_quick",
                     "convergence_time": conv[k] * (1 + noise * rng.standard_normal())
                     if task in TASKS else np.nan,
                     "tip_rms_cm": tracking[k] * (1 + noise * rng.standard_normal())}
                )  # fmt: skip
    return pd.DataFrame(rows)


def _by_claim(episodes: pd.DataFrame) -> dict[str, pd.Series]:
    numbers = claim_check(episodes).numbers
    return {row.claim: row for _, row in numbers.iterrows()}


def test_a_clear_win_confirms_both_claims_over_seeds() -> None:
    out = _by_claim(_episodes(5, conv=(0.15, 0.8), tracking=(0.08, 1.0)))
    conv, acc = out["faster convergence"], out["better accuracy"]
    assert (conv.runs, conv.episodes, acc.episodes) == (5, 4, 24)
    assert conv.improvement == pytest.approx(1 - 0.15 / 0.8, abs=0.02)
    assert conv.ci_low <= conv.improvement <= conv.ci_high
    assert conv.ci_low > 0.10 and acc.ci_low > 0.18
    assert conv.verdict == acc.verdict == "confirmed"
    assert conv.prob_improvement == 1.0 and acc.prob_improvement == 1.0


def test_small_and_negative_effects() -> None:
    """5 % better: direction only against a 10 % claim; 10 % worse: refuted; equal: not
    confirmed either way."""
    assert _by_claim(_episodes(5, (0.95, 1.0), (1.0, 1.0)))["faster convergence"].verdict == (
        "direction only"
    )
    worse = _by_claim(_episodes(5, (1.1, 1.0), (1.1, 1.0)))
    assert worse["faster convergence"].verdict == worse["better accuracy"].verdict == "refuted"
    assert worse["better accuracy"].improvement == pytest.approx(-0.1, abs=0.02)
    same = _by_claim(_episodes(5, (1.0, 1.0), (1.0, 1.0), noise=0.05))
    assert same["better accuracy"].verdict in ("inconclusive", "direction only", "refuted")
    assert same["better accuracy"].verdict != "confirmed"


def test_missed_and_never_settled_episodes_are_left_out() -> None:
    episodes = _episodes(3, (0.15, 0.8), (0.08, 1.0))
    missed = (episodes.task == "b") & (episodes.controller == "pid") & (episodes.eval_run == "run1")
    episodes.loc[missed, "success"] = 0.0
    never = (episodes.task == "c") & (episodes.controller == "adaptive")
    episodes.loc[never, "convergence_time"] = np.inf
    out = _by_claim(episodes)
    assert out["faster convergence"].episodes == 2  # (a) and (d)
    assert out["better accuracy"].episodes == 23  # all but (b)


def test_one_seed_measures_the_claim_but_gives_no_verdict_and_says_why() -> None:
    table = claim_check(_episodes(1, (0.15, 0.8), (0.08, 1.0), noise=0.2))
    acc = table.numbers.set_index("claim").loc["better accuracy"]
    assert acc.runs == 1 and acc.seeds == 1
    assert acc.improvement == pytest.approx((acc.iqm_pid - acc.iqm_proposed) / acc.iqm_pid)
    assert np.isnan(acc.ci_low) and np.isnan(acc.ci_high)
    assert set(table.numbers.verdict) == {"none (needs ≥ 2 seeds)"}
    assert any("No verdict where fewer than 2 seeds" in note for note in table.notes)
    md = table.markdown()
    assert "| confirmed |" not in md and "1 × 24" in md


def test_a_ratio_against_a_zero_is_a_dash_not_a_verdict() -> None:
    episodes = _episodes(3, (0.15, 0.8), (0.08, 1.0))
    episodes.loc[episodes.controller == "pid", "tip_rms_cm"] = 0.0
    acc = claim_check(episodes).shown.set_index("Claim").loc["better accuracy (paper: ≈ 18 %)"]
    assert acc["Improvement [95 % CI]"] == "–" and acc.Verdict == "inconclusive"
    assert "100" not in acc["Improvement [95 % CI]"]


def test_an_agent_evaluated_without_pid_is_left_out() -> None:
    episodes = _episodes(3, (0.15, 0.8), (0.08, 1.0))
    paper = episodes[episodes.controller == "adaptive"].assign(agent="sac_quick, paper gains")
    table = claim_check(pd.concat([episodes, paper], ignore_index=True))
    assert len(table.numbers) == 2 and set(table.numbers.verdict) == {"confirmed"}


def test_nothing_reached_by_both_is_inconclusive() -> None:
    episodes = _episodes(2, (0.15, 0.8), (0.08, 1.0))
    episodes.loc[episodes.controller == "pid", "success"] = 0.0
    table = claim_check(episodes)
    assert set(table.numbers.verdict) == {"inconclusive"}
    assert (table.shown["Improvement [95 % CI]"] == "–").all()
