"""The controller comparison, the ablation, the tuning spread and the label reading
(`armexp.report.comparison`, `.tuning`, `.labels`) on synthetic data with known answers."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest

from armexp.report import comparison, figures, labels, tuning

TASKS = ("a", "b", "c", "d")


def _frame(runs: int, values: dict[str, tuple[str, float, float]], noise: float = 0.02) -> Any:
    """Episodes with label columns: label → (role, decay rate 1/s, tip RMS cm)."""
    rng = np.random.default_rng(4)
    rows = []
    for r in range(runs):
        for task in (*TASKS, "random_000", "random_001"):
            for label, (role, rate, tip) in values.items():
                rows.append(
                    {"eval_run": f"e{r}", "seed": str(r), "controller": label, "task": task,
                     "success": 1.0, "role": role, "stored_label": label,
                     "controller_name": "pid" if role == "baseline" else "subsystem_adaptive",
                     "criterion": "itae", "horizon": 1.5,
                     "compare_with": "adaptive" if role == "baseline" else "",
                     "tune_run": "", "tuner_seed": float(r), "gains_text": "",
                     "decay_rate": rate * (1 + noise * rng.standard_normal())
                     if task in TASKS else np.nan,
                     "tip_rms_cm": tip * (1 + noise * rng.standard_normal()),
                     "max_abs_tau_1": 100.0 + r, "max_abs_tau_2": 50.0}
                )  # fmt: skip
    return pd.DataFrame(rows)


def test_the_comparison_orders_labels_by_role_and_counts_the_tasks_a_cell_covers() -> None:
    episodes = _frame(
        4,
        {
            "pid_itae": ("baseline", 8.0, 0.03),
            "adaptive_off": ("ablation", 28.0, 0.09),
            "adaptive": ("proposed", 28.0, 0.09),
        },
    )
    episodes.loc[(episodes.controller == "pid_itae") & (episodes.task == "c"), "decay_rate"] = (
        np.inf
    )
    table = comparison.comparison(episodes)
    assert list(table.shown.Label) == ["adaptive", "adaptive_off", "pid_itae"]
    pid = table.numbers.set_index("label").loc["pid_itae"]
    assert pid.decay_rate == pytest.approx(8.0, rel=0.03) and pid.decay_rate_episodes == 3
    assert pid.max_torque == pytest.approx(np.mean([101.0, 102.0]))  # IQM of 100..103 per task
    shown = table.shown.set_index("Label").loc["pid_itae"]
    assert shown["Decay rate α (1/s)"].endswith("(3/4 tasks)")
    assert shown["Ultimate bound α* (mrad)"] == "–"  # not logged


@pytest.mark.parametrize(
    ("factor", "runs", "start"),
    [
        (1.2, 5, "Adaptation contributes:"),
        (1.0, 5, "Adaptation does not measurably contribute (every CI includes 0)"),
        (0.8, 5, "Adaptation does not measurably contribute (the law does better"),
        (1.2, 1, "Adaptation's contribution is not judged (one seed, no CI)"),
    ],
)
def test_the_ablation_sentence_follows_the_ci(factor: float, runs: int, start: str) -> None:
    """Adaptation off: the tip RMS error of every episode times ``factor`` (1.0: an inert law,
    the same numbers), the decay rate unchanged."""
    values = {"adaptive": ("proposed", 28.0, 0.09), "adaptive_off": ("ablation", 28.0, 0.09)}
    episodes = _frame(runs, values, noise=0.05)
    on, off = (episodes.controller == lab for lab in ("adaptive", "adaptive_off"))
    for key, scale in (("tip_rms_cm", factor), ("decay_rate", 1.0)):
        episodes.loc[off, key] = episodes.loc[on, key].to_numpy() * scale
    (row,) = comparison.ablation(episodes).numbers.to_dict("records")
    assert row["sentence"].startswith(start)
    assert row["tip_rms_cm_change"] == pytest.approx(factor - 1)
    assert row["time_constant_change"] == pytest.approx(0.0)
    assert "tip RMS error changes by" in row["sentence"]
    assert row["time_constant_episodes"] == 4


def test_the_ablation_is_empty_without_an_ablation_label() -> None:
    table = comparison.ablation(_frame(2, {"adaptive": ("proposed", 28.0, 0.09)}))
    assert table.shown.empty


def _tune(run_id: str, controller: str, criterion: str, seed: int | None, **kw: Any) -> Any:
    return {"run_id": run_id, "controller": controller, "criterion": criterion,
            "horizon": kw.get("horizon", 1.5), "tuner_seed": seed,
            "gains": kw.get("gains", {"kp_1": 100.0, "kd_1": 10.0}), "best": kw.get("best", 1.0),
            "paper_objective": math.nan, "on_bound": kw.get("on_bound", []),
            "history": pd.DataFrame(), "labels": []}  # fmt: skip


def test_the_tuning_spread_groups_by_controller_and_criterion() -> None:
    tunes = [
        _tune("t0", "pid", "gaing", 0, horizon=0.6, on_bound=["ki_1=lower"], best=0.26),
        _tune("t1", "pid", "gaing", 1, horizon=0.6, on_bound=["ki_1=lower"], best=0.26),
        _tune("t2", "pid", "gaing", 2, horizon=0.6, on_bound=[], best=0.26),
        _tune("u0", "pid", "itae", 0, gains={"kp_1": 90.0, "kd_1": 10.0}, best=0.1),
        _tune("u1", "pid", "itae", 1, gains={"kp_1": 110.0, "kd_1": 12.0}, best=0.3),
        _tune("v0", "computed_torque", "itae", 0, on_bound=None),
        _tune("v1", "computed_torque", "itae", 0, on_bound=None),
    ]
    got = tuning.spread(tunes)
    gaing = got[("pid", "gaing", 0.6)]
    assert gaing["identical"] and gaing["vectors"] == 1 and gaing["seeds"] == [0, 1, 2]
    assert gaing["on_bound"] == "ki_1=lower (2/3)"
    itae = got[("pid", "itae", 1.5)]
    assert not itae["identical"] and itae["vectors"] == 2
    assert (itae["best_min"], itae["best_max"]) == (0.1, 0.3)
    assert itae["gains"]["kp_1"] == [90.0, 110.0]
    same_seed = got[("computed_torque", "itae", 1.5)]
    assert not same_seed["identical"]  # one tuner seed: identical by construction, not said
    assert same_seed["on_bound"] == "not logged"
    table = tuning.spread_table(tunes)
    rows = table.shown.set_index(["Controller", "Criterion"])
    assert rows.loc[("pid", "itae over 1.5 s"), "Gains (min–max)"] == "kp_1 90–110; kd_1 10–12"
    assert rows.loc[("computed_torque", "itae over 1.5 s"), "Tuner seeds"] == "0 (all 2 runs)"
    assert any("identical gains at all 3 seeds (0, 1, 2)" in n for n in table.notes)


def _run(tags: dict[str, str], params: dict[str, str]) -> Any:
    return SimpleNamespace(data=SimpleNamespace(tags=tags, params=params, metrics={}))


def test_a_tune_runs_criterion_comes_from_its_tags_else_its_config_else_the_papers() -> None:
    assert labels.tune_criterion(
        _run({"armexp.criterion": "itae", "armexp.horizon": "1.5"}, {})
    ) == ("itae", 1.5)
    assert labels.tune_criterion(_run({}, {"tuner.objective.horizon": "0.4"})) == ("gaing", 0.4)
    assert labels.tune_criterion(_run({}, {})) == ("gaing", 0.6)


def test_old_eval_runs_labels_and_their_tune_runs() -> None:
    tune = _run({}, {"tuner.seed": "3", "tuner.objective.horizon": "0.6", "tuned.kp_1": "5"})
    got = labels.of_run(
        None,
        ["adaptive", "pid"],
        {"armexp.tune_run": "ta", "armexp.pid_tune_run": "tp"},
        {"eval.pid_gains": "tuned"},
        {"tp": tune},
    )
    assert list(got) == ["adaptive", "pid_gaing"]
    pid = got["pid_gaing"]
    assert (pid.stored, pid.role, pid.compare_with, pid.criterion) == (
        "pid", "baseline", "adaptive", "gaing"
    )  # fmt: skip
    assert pid.tuner_seed == 3.0 and pid.gains == "kp_1=5" and pid.horizon == 0.6
    assert got["adaptive"].tune_run == "ta" and math.isnan(got["adaptive"].tuner_seed)
    configured = labels.of_run(None, ["adaptive", "pid"], {"armexp.adaptive_gains": "config"},
                               {"eval.pid_gains": "config"}, {})  # fmt: skip
    assert {lab.criterion for lab in configured.values()} == {"config"}
    # An old eval run whose PID tune run already names its criterion is reported under it.
    itae = _run({"armexp.criterion": "itae", "armexp.horizon": "1.5"}, {"tuner.seed": "0"})
    renamed = labels.of_run(None, ["adaptive", "pid"], {"armexp.pid_tune_run": "tp"}, {},
                            {"tp": itae})  # fmt: skip
    assert list(renamed) == ["adaptive", "pid_itae"] and renamed["pid_itae"].stored == "pid"
    # A PID-trained policy's old eval: pid is its own, proposed controller.
    (own,) = labels.of_run(None, ["pid"], {}, {}, {}).values()
    assert (own.name, own.role) == ("pid", "proposed")


def test_controllers_yaml_names_the_labels_and_annotate_writes_them_into_episodes() -> None:
    declared = {
        "adaptive": {"controller": "subsystem_adaptive", "role": "proposed", "criterion": "itae",
                     "horizon": 1.5, "tune_run": "ta", "gains": {"a0": 1.0}, "compare_with": None},
        "pid_itae": {"controller": "pid", "role": "baseline", "criterion": "itae",
                     "horizon": 1.5, "tune_run": None, "gains": {"kp": [1.0, 2.0]},
                     "compare_with": "adaptive"},
    }  # fmt: skip
    tags = {"armexp.tune_run.pid_itae": "tp"}
    got = labels.of_run(declared, [], tags, {}, {})
    assert got["pid_itae"].tune_run == "tp" and got["pid_itae"].gains == "kp_1=1, kp_2=2"
    frame = pd.DataFrame({"controller": ["adaptive", "pid_itae"], "task": ["a", "a"]})
    out = labels.annotate(frame, got)
    assert list(out.role) == ["proposed", "baseline"]
    assert labels.comparisons(out) == [("pid_itae", "adaptive")]
    assert labels.describe(out, "pid_itae") == "pid_itae (pid, itae over 1.5 s)"


def _trajectory(scale: float) -> pd.DataFrame:
    t = np.linspace(0, 1, 50)
    return pd.DataFrame({"t": t, "q_1": t, "q_2": -t, "q_d_1": t, "q_d_2": -t,
                         "tau_1": scale * t, "tau_2": -scale * t})  # fmt: skip


def test_fig5_has_a_column_per_label_and_fig6_a_pair_per_label() -> None:
    frames = {label: {task: _trajectory(i + 1) for task in TASKS}
              for i, label in enumerate(("adaptive", "pid_gaing", "computed_torque"))}  # fmt: skip
    fig5 = figures.torques(frames)
    assert len(fig5.axes) == 2 * 3
    assert [ax.get_title() for ax in fig5.axes[:3]] == ["adaptive", "pid_gaing", "computed_torque"]
    fig6 = figures.tracking({"adaptive": _trajectory(1), "pid_gaing": _trajectory(2)}, "a")
    assert len(fig6.axes) == 2 * 4
    plt.close(fig5)
    plt.close(fig6)
