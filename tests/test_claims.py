"""The claim check (docs/design.md §9) on episode tables with known outcomes: one two-sided
verdict per claim and baseline."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from armexp.report.claims import claim_check
from tests.helpers import row_at

TASKS = ("a", "b", "c", "d")
#: label → (controller, role, criterion, horizon, compare_with)
LABELS = {
    "adaptive": ("subsystem_adaptive", "proposed", "itae", 1.5, ""),
    "adaptive_off": ("subsystem_adaptive", "ablation", "itae", 1.5, ""),
    "adaptive_gaing": ("subsystem_adaptive", "reference", "gaing", 0.6, ""),
    "pid_gaing": ("pid", "baseline", "gaing", 0.6, "adaptive_gaing"),
    "pid_itae": ("pid", "baseline", "itae", 1.5, "adaptive"),
    "computed_torque": ("computed_torque", "baseline", "itae", 1.5, "adaptive"),
}


def _episodes(
    runs: int,
    values: dict[str, tuple[float, float]],
    noise: float = 0.02,
    tuner_seeds: bool = True,
    same_gains: bool = False,
) -> pd.DataFrame:
    """Episodes of ``runs`` eval runs in the new format: the paper tasks and 20 held-out targets
    per label of ``values`` (label → (time constant s, tip RMS cm)), with the label columns the
    report reads from ``controllers.yaml``."""
    rng = np.random.default_rng(0)
    rows = []
    for r in range(runs):
        for task in (*TASKS, *(f"random_{i:03d}" for i in range(20))):
            for label, (tau, tracking) in values.items():
                controller, role, criterion, horizon, compare = LABELS[label]
                paper = task in TASKS
                seed = float(r) if tuner_seeds else 0.0
                rows.append(
                    {"eval_run": f"run{r}", "seed": str(r), "controller": label, "task": task,
                     "success": 1.0, "agent": "sac_quick", "stored_label": label,
                     "controller_name": controller, "role": role, "criterion": criterion,
                     "horizon": horizon, "compare_with": compare, "tune_run": f"t{label}{r}",
                     "tuner_seed": seed,
                     "gains_text": f"kp={1 if same_gains else seed}",
                     "decay_rate": 1 / (tau * (1 + noise * rng.standard_normal()))
                     if paper else np.nan,
                     "tip_rms_cm": tracking * (1 + noise * rng.standard_normal())}
                )  # fmt: skip
    return pd.DataFrame(rows)


def _numbers(episodes: pd.DataFrame) -> pd.DataFrame:
    return claim_check(episodes).numbers.set_index(["claim", "baseline"])


def test_a_clear_win_is_larger_than_claimed_not_a_reproduction() -> None:
    out = _numbers(_episodes(5, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)}))
    conv = row_at(out, ("faster convergence", "pid_itae"))
    acc = row_at(out, ("better accuracy", "pid_itae"))
    assert (conv.runs, conv.episodes, acc.episodes) == (5, 4, 24)
    assert conv.improvement == pytest.approx(1 - 0.15 / 0.8, abs=0.02)
    assert conv.ci_low <= conv.improvement <= conv.ci_high
    assert conv.verdict == acc.verdict == "larger than claimed"
    assert conv.prob_improvement == 1.0 and acc.prob_improvement == 1.0
    assert conv.proposed == "adaptive" and conv.criterion == "itae" and conv.horizon == 1.5


@pytest.mark.parametrize(
    ("tau", "tracking", "noise", "conv_verdict", "acc_verdict"),
    [
        (0.9, 0.82, 0.02, "consistent", "consistent"),  # 10 % and 18 % better
        (0.97, 0.95, 0.01, "smaller than claimed", "smaller than claimed"),  # 3 % and 5 %
        (1.1, 1.1, 0.02, "refuted", "refuted"),  # 10 % worse
        (1.0, 1.0, 0.05, "inconclusive", "inconclusive"),  # the same
    ],
)
def test_each_verdict_word_against_a_baseline(
    tau: float, tracking: float, noise: float, conv_verdict: str, acc_verdict: str
) -> None:
    out = _numbers(_episodes(8, {"adaptive": (tau, tracking), "pid_itae": (1.0, 1.0)}, noise=noise))
    assert row_at(out, ("faster convergence", "pid_itae")).verdict == conv_verdict
    assert row_at(out, ("better accuracy", "pid_itae")).verdict == acc_verdict


def test_one_row_per_claim_and_baseline_each_against_its_own_proposed_side() -> None:
    values = {
        "adaptive": (0.15, 0.08),
        "adaptive_off": (0.15, 0.08),
        "adaptive_gaing": (0.2, 0.1),
        "pid_gaing": (0.8, 1.0),
        "pid_itae": (0.1, 0.02),
        "computed_torque": (0.16, 0.085),
    }
    table = claim_check(_episodes(5, values))
    numbers = table.numbers
    assert list(zip(numbers.baseline, numbers.claim, strict=True)) == [
        (b, c)
        for b in ("pid_gaing", "pid_itae", "computed_torque")
        for c in ("faster convergence", "better accuracy")
    ]
    by = numbers.set_index(["claim", "baseline"]).verdict
    assert by[("faster convergence", "pid_gaing")] == "larger than claimed"
    assert by[("better accuracy", "pid_itae")] == "refuted"  # the ITAE PID tracks better
    assert by[("faster convergence", "pid_itae")] == "refuted"
    assert by[("better accuracy", "computed_torque")] in ("inconclusive", "smaller than claimed")
    proposed = numbers.set_index("baseline").proposed
    assert proposed["pid_gaing"].iloc[0] == "adaptive_gaing"
    assert proposed["computed_torque"].iloc[0] == "adaptive"
    shown = table.shown.set_index("Baseline")
    assert "pid_gaing (pid, gaing over 0.6 s)" in shown.index
    assert shown.loc[["pid_itae (pid, itae over 1.5 s)"], "Proposed"].iloc[0] == (
        "adaptive (subsystem_adaptive, itae over 1.5 s)"
    )
    notes = " ".join(table.notes)
    for word in ("consistent", "larger than claimed", "smaller than claimed", "refuted"):
        assert word in notes
    assert "confirmed" not in table.markdown() and "direction only" not in table.markdown()


@pytest.mark.long
def test_the_ci_says_whether_it_includes_the_tuning() -> None:
    values = {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)}
    varied = _numbers(_episodes(5, values)).ci_covers.iloc[0]
    assert varied == (
        "adaptive: policy and tuning (5 tuner seeds); pid_itae: policy and tuning (5 tuner seeds)"
    )
    fixed = _numbers(_episodes(5, values, tuner_seeds=False)).ci_covers.iloc[0]
    assert "pid_itae: policy only (tuner seed 0 at every run)" in fixed
    same = _numbers(_episodes(5, values, same_gains=True)).ci_covers.iloc[0]
    assert "pid_itae: policy only (identical gains at all 5 tuner seeds)" in same
    configured = _episodes(5, values).assign(criterion="config")
    assert "policy only (configured gains)" in _numbers(configured).ci_covers.iloc[0]
    assert any("tuner.seed" in note for note in claim_check(_episodes(5, values)).notes)


def test_convergence_is_the_time_constant_and_a_task_that_never_decays_is_left_out() -> None:
    episodes = _episodes(3, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)})
    episodes.loc[(episodes.task == "c") & (episodes.controller == "adaptive"), "decay_rate"] = 0.0
    never = (episodes.task == "d") & (episodes.controller == "pid_itae")
    episodes.loc[never, "decay_rate"] = np.nan
    missed = (episodes.task == "b") & (episodes.controller == "pid_itae")
    episodes.loc[missed & (episodes.eval_run == "run1"), "success"] = 0.0
    out = _numbers(episodes)
    conv = row_at(out, ("faster convergence", "pid_itae"))
    assert conv.episodes == 2  # (a), (b): the offset run does not depend on reaching the target
    assert conv.metric == "time_constant"
    assert row_at(out, ("better accuracy", "pid_itae")).episodes == 23  # all but (b)


def test_old_eval_runs_read_as_adaptive_against_pid_gaing_without_a_convergence_verdict() -> None:
    """Frames of eval runs made before controllers.yaml: labels adaptive and pid, the old
    run-subtraction convergence_time and no decay rate."""
    rng = np.random.default_rng(1)
    rows = [
        {"eval_run": f"run{r}", "controller": controller, "task": task, "success": 1.0,
         "convergence_time": 0.1, "tip_rms_cm": base * (1 + 0.02 * rng.standard_normal())}
        for r in range(4)
        for task in (*TASKS, "random_000", "random_001")
        for controller, base in (("adaptive", 0.5), ("pid", 1.0))
    ]  # fmt: skip
    table = claim_check(pd.DataFrame(rows))
    by = table.numbers.set_index("claim")
    assert set(table.numbers.baseline) == {"pid_gaing"}
    assert set(table.numbers.proposed) == {"adaptive"}
    assert by.loc["faster convergence"].verdict == "–"
    assert by.loc["better accuracy"].verdict == "larger than claimed"
    assert by.loc["better accuracy"].criterion == "gaing"
    assert by.loc["better accuracy"].horizon == 0.6
    assert any("made before the Definition-1 measures" in n for n in table.notes)
    assert table.shown.Baseline.iloc[0] == "pid_gaing (pid, gaing over 0.6 s)"


def test_one_seed_measures_the_claim_but_gives_no_verdict_and_says_why() -> None:
    table = claim_check(_episodes(1, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)}, 0.2))
    acc = table.numbers.set_index("claim").loc["better accuracy"]
    assert acc.runs == 1 and acc.seeds == 1
    assert acc.improvement == pytest.approx(
        (acc.iqm_baseline - acc.iqm_proposed) / acc.iqm_baseline
    )
    assert np.isnan(acc.ci_low) and np.isnan(acc.ci_high)
    assert set(table.numbers.verdict) == {"none (needs ≥ 2 seeds)"}
    assert any("No verdict where fewer than 2 seeds" in note for note in table.notes)
    assert "1 × 24" in table.markdown()


def test_a_ratio_against_a_zero_is_a_dash_not_a_verdict() -> None:
    episodes = _episodes(3, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)})
    episodes.loc[episodes.controller == "pid_itae", "tip_rms_cm"] = 0.0
    shown = claim_check(episodes).shown.set_index("Claim")
    acc = shown.loc["better accuracy (paper: ≈ 18 %)"]
    assert acc["Improvement [95 % CI]"] == "–" and acc.Verdict == "inconclusive"


def test_an_agent_evaluated_without_a_baseline_is_left_out() -> None:
    episodes = _episodes(3, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)})
    paper = episodes[episodes.controller == "adaptive"].assign(agent="sac_quick, paper gains")
    table = claim_check(pd.concat([episodes, paper], ignore_index=True))
    assert len(table.numbers) == 2 and set(table.numbers.verdict) == {"larger than claimed"}
    assert set(table.numbers.agent) == {"sac_quick (plain)"}


def test_nothing_reached_by_both_leaves_accuracy_inconclusive() -> None:
    episodes = _episodes(2, {"adaptive": (0.15, 0.08), "pid_itae": (0.8, 1.0)})
    episodes.loc[episodes.controller == "pid_itae", "success"] = 0.0
    by = claim_check(episodes).numbers.set_index("claim")
    assert by.loc["better accuracy"].verdict == "inconclusive"
    assert by.loc["better accuracy"].episodes == 0
    assert by.loc["faster convergence"].episodes == 4


def test_no_baseline_at_all_is_an_empty_table_that_says_so() -> None:
    episodes = _episodes(2, {"adaptive": (0.15, 0.08)})
    table = claim_check(episodes)
    assert table.numbers.empty
    assert any("No baseline" in n for n in table.notes)


def test_the_paper_gains_config_holds_the_papers_printed_gains() -> None:
    # Hydra composes controller.gains=paper from the config tree; armexp.paper is the one place
    # the report, the tuner and the simulator take the printed gains from.
    from omegaconf import OmegaConf

    from armexp import paper
    from armexp.config import config_dir
    from armexp.sim.controllers import PAPER_GAINS

    stored = OmegaConf.to_container(OmegaConf.load(config_dir() / "controller/gains/paper.yaml"))
    assert stored == paper.GAINS and PAPER_GAINS is paper.GAINS
