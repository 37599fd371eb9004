"""armexp.report.seed_figures on hand-made histories and evaluation episodes."""

from __future__ import annotations

import matplotlib.pyplot as plt
import numpy as np
import pandas as pd
import pytest
from matplotlib.figure import Figure
from scipy import stats as sps

from armexp.report.seed_figures import (
    BAND_COLUMNS,
    PROFILE_COLUMNS,
    curve_band,
    learning_curves_ci,
    performance_profiles,
    profile_curves,
    series_names,
)

N_BOOT = 300


def _history(steps: list[int], values: list[float]) -> pd.DataFrame:
    return pd.DataFrame({"step": steps, "value": values})


# Three runs on different step grids; the shortest ends at step 300.
RUNS = [
    _history([0, 100, 200, 300, 400], [0.0, 0.2, 0.4, 0.6, 0.8]),
    _history([0, 150, 300], [0.0, 0.3, 0.9]),
    _history([0, 50, 250, 350], [0.1, 0.2, 0.6, 1.0]),
]


# -- curve_band --------------------------------------------------------------------------------


def test_curve_band_grid_is_union_up_to_shortest_last_step() -> None:
    band = curve_band(RUNS, n_boot=N_BOOT)
    assert list(band.columns) == BAND_COLUMNS
    assert band["step"].tolist() == [0, 50, 100, 150, 200, 250, 300]
    assert band["step"].iloc[-1] == 300  # run 2's last step, the smallest
    assert (band["runs"] == 3).all()


def test_curve_band_iqm_is_interpolated_trim_mean() -> None:
    band = curve_band(RUNS, n_boot=N_BOOT).set_index("step")
    # At step 150: run 1 interpolates 0.2→0.4 halfway = 0.3, run 2 has 0.3 exactly,
    # run 3 interpolates 0.2 (step 50) → 0.6 (step 250) at 1/2 = 0.4.
    at_150 = [0.3, 0.3, 0.4]
    expected = sps.trim_mean(at_150, 0.25)
    assert band.loc[150, "iqm"] == pytest.approx(expected)
    assert band.loc[150, "iqm"] == pytest.approx(1.0 / 3.0)  # 3 values: nothing trimmed
    # At step 300: 0.6, 0.9 and 0.6 + 0.4 * (50/100) = 0.8.
    assert band.loc[300, "iqm"] == pytest.approx(sps.trim_mean([0.6, 0.9, 0.8], 0.25))


def test_curve_band_band_contains_point_and_is_deterministic() -> None:
    rng = np.random.default_rng(3)
    steps = list(range(0, 1000, 100))
    runs = [
        _history(steps, list(np.clip(np.linspace(0, 1, 10) + rng.normal(0, 0.1, 10), 0, 1)))
        for _ in range(6)
    ]
    band = curve_band(runs, n_boot=N_BOOT, seed=1)
    assert np.isfinite(band[["low", "high"]].to_numpy()).all()
    assert (band["low"] <= band["iqm"] + 1e-12).all()
    assert (band["iqm"] <= band["high"] + 1e-12).all()
    assert (band["high"] - band["low"]).max() > 0
    matrix = np.array([r["value"].to_numpy() for r in runs])
    assert band["iqm"].to_numpy() == pytest.approx(sps.trim_mean(matrix, 0.25, axis=0))
    pd.testing.assert_frame_equal(band, curve_band(runs, n_boot=N_BOOT, seed=1))


def test_curve_band_single_run_has_nan_band() -> None:
    band = curve_band([RUNS[1]], n_boot=N_BOOT)
    assert band["step"].tolist() == [0, 150, 300]
    assert band["iqm"].tolist() == pytest.approx([0.0, 0.3, 0.9])
    assert band["low"].isna().all() and band["high"].isna().all()
    assert (band["runs"] == 1).all()


def test_curve_band_empty_inputs() -> None:
    for histories in ([], [_history([], [])]):
        band = curve_band(histories, n_boot=N_BOOT)
        assert band.empty
        assert list(band.columns) == BAND_COLUMNS


def test_curve_band_skips_empty_histories() -> None:
    band = curve_band([RUNS[0], _history([], []), RUNS[1]], n_boot=N_BOOT)
    assert (band["runs"] == 2).all()
    assert band["step"].iloc[-1] == 300


def test_learning_curves_ci_lines_and_legend() -> None:
    fig = learning_curves_ci(
        {"sac_quick (aided)": RUNS, "sac_paper (plain)": [RUNS[0]]}, n_boot=N_BOOT
    )
    try:
        assert isinstance(fig, Figure)
        ax = fig.axes[0]
        assert len(ax.get_lines()) == 2
        legend = ax.get_legend()
        assert legend is not None
        texts = [t.get_text() for t in legend.get_texts()]
        assert texts == ["sac_quick (aided), 3 seeds", "sac_paper (plain), 1 seed"]
        assert len(ax.collections) == 1  # a band only for the group with several runs
        assert ax.get_ylim() == pytest.approx((-0.02, 1.02))
        assert ax.get_xlabel() == "environment steps"
    finally:
        plt.close(fig)


# -- performance profiles ----------------------------------------------------------------------

SUCCESS = {  # (agent, controller) -> per-run success of the 4 held-out targets
    ("sac", "adaptive"): [[1, 1, 1, 0], [1, 0, 0, 0], [1, 1, 0, 0], [1, 1, 1, 1]],
    ("sac", "pid"): [[0, 0, 0, 0], [1, 0, 0, 0], [1, 1, 1, 0]],
}


def _episodes() -> pd.DataFrame:
    rng = np.random.default_rng(0)
    rows = []
    for (agent, controller), runs in SUCCESS.items():
        scale = 1.0 if controller == "adaptive" else 3.0
        for seed, successes in enumerate(runs):
            run = {"eval_run": f"{agent}-{controller}-{seed}", "seed": seed, "agent": agent,
                   "controller": controller}  # fmt: skip
            for k, s in enumerate(successes):
                error = scale * float(rng.uniform(0.5, 5.0))
                rows.append({**run, "task": f"random_{k:03d}", "success": float(s),
                             "tip_rms_cm": error})  # fmt: skip
            # Paper tasks: huge errors and failures, to be ignored.
            rows += [{**run, "task": t, "success": 0.0, "tip_rms_cm": 1000.0} for t in "abcd"]
    return pd.DataFrame(rows)


def test_profile_curves_success_profile() -> None:
    curves = profile_curves(_episodes(), n_boot=N_BOOT)
    assert sorted(curves) == ["sac, adaptive", "sac, pid"]
    for (agent, controller), runs in SUCCESS.items():
        frame = curves[f"{agent}, {controller}"]["success"]
        assert list(frame.columns) == PROFILE_COLUMNS
        assert frame["tau"].to_numpy() == pytest.approx(np.linspace(0, 1, 101))
        rates = np.mean(np.array(runs, dtype=float), axis=1)
        fraction = frame["fraction"].to_numpy()  # τ = i / 100
        assert fraction[50] == pytest.approx(np.mean(rates > 0.5))
        assert fraction[0] == pytest.approx(np.mean(rates > 0.0))
        assert fraction[100] == 0.0
    adaptive = curves["sac, adaptive"]["success"].set_index("tau")
    # rates 0.75, 0.25, 0.5, 1.0: half of the runs score above 0.5 (paper tasks would lower them).
    assert adaptive["fraction"].iloc[50] == pytest.approx(0.5)
    assert (adaptive["low"] <= adaptive["fraction"] + 1e-12).all()
    assert (adaptive["fraction"] <= adaptive["high"] + 1e-12).all()


def test_profile_curves_tracking_profile() -> None:
    episodes = _episodes()
    curves = profile_curves(episodes, n_boot=N_BOOT)
    held = episodes[episodes.task.str.startswith("random_")]
    lo, hi = held.tip_rms_cm.min(), held.tip_rms_cm.max()
    for key in ("sac, adaptive", "sac, pid"):
        frame = curves[key]["tracking"]
        assert list(frame.columns) == PROFILE_COLUMNS
        tau = frame["tau"].to_numpy()
        assert len(tau) == 100
        assert tau[0] == pytest.approx(lo) and tau[-1] == pytest.approx(hi)  # shared, no 1000
        assert np.all(np.diff(frame["fraction"].to_numpy()) >= 0)
        assert frame["fraction"].iloc[-1] == 1.0
        assert frame["fraction"].iloc[0] == 0.0
    a, p = curves["sac, adaptive"]["tracking"], curves["sac, pid"]["tracking"]
    assert np.array_equal(a["tau"].to_numpy(), p["tau"].to_numpy())
    # Check one interior τ against a direct count over the held-out episodes.
    i = 40
    pid_errors = held[held.controller == "pid"].tip_rms_cm.to_numpy()
    assert p["fraction"].iloc[i] == pytest.approx(np.mean(pid_errors < p["tau"].iloc[i]))


def test_profile_curves_single_run_and_missing_targets() -> None:
    episodes = _episodes()
    one = episodes[episodes.eval_run.isin(["sac-adaptive-0", "sac-pid-0", "sac-pid-1"])]
    # Target random_003 missing for one pid run: that column is dropped for pid only.
    one = one[~((one.eval_run == "sac-pid-1") & (one.task == "random_003"))]
    curves = profile_curves(one, n_boot=N_BOOT)
    adaptive = curves["sac, adaptive"]
    assert adaptive["success"]["low"].isna().all() and adaptive["tracking"]["high"].isna().all()
    assert adaptive["success"]["fraction"].iloc[50] == 1.0  # one run, success rate 0.75
    pid = curves["sac, pid"]["tracking"]
    pid_rows = one[(one.controller == "pid") & one.task.str.startswith("random_")]
    kept = pid_rows[pid_rows.task != "random_003"]
    tau = pid["tau"].iloc[60]
    assert pid["fraction"].iloc[60] == pytest.approx(np.mean(kept.tip_rms_cm < tau))


def test_performance_profiles_figure() -> None:
    fig = performance_profiles(_episodes(), n_boot=N_BOOT)
    assert fig is not None
    try:
        assert isinstance(fig, Figure)
        left, right = fig.axes
        assert len(left.get_lines()) == 2 and len(right.get_lines()) == 2
        assert right.get_xscale() == "log"
        legend = left.get_legend()
        assert legend is not None
        assert [t.get_text() for t in legend.get_texts()] == ["sac, adaptive", "sac, pid"]
        for ax in (left, right):
            solid, dashed = ax.get_lines()
            assert solid.get_linestyle() == "-" and dashed.get_linestyle() == "--"
        assert [ln.get_color() for ln in left.get_lines()] == [
            ln.get_color() for ln in right.get_lines()
        ]
        assert left.get_title() == "held-out success" and right.get_title() == "tracking error"
    finally:
        plt.close(fig)


def test_performance_profiles_legend_names_preset_and_controller_only() -> None:
    described = (
        "crossq_plain_guard_late (learning aids without privileged knowledge: guard, late phase)"
    )
    episodes = _episodes()
    episodes["agent"] = described
    episodes["agent_preset"] = "crossq_plain_guard_late"
    fig = performance_profiles(episodes, n_boot=N_BOOT)
    assert fig is not None
    try:
        legend = fig.axes[0].get_legend()
        assert legend is not None
        assert [t.get_text() for t in legend.get_texts()] == [
            "crossq_plain_guard_late, adaptive",
            "crossq_plain_guard_late, pid",
        ]
    finally:
        plt.close(fig)
    # Two agents of one preset (a study's tuned and paper gains) keep distinct entries.
    other = _episodes()
    other["agent"] = described + ", paper gains"
    other["agent_preset"] = "crossq_plain_guard_late"
    both = pd.concat([episodes, other], ignore_index=True)
    entries = set(series_names(both).values())
    assert len(entries) == 4


def test_performance_profiles_none_without_held_out_rows() -> None:
    episodes = _episodes()
    paper_only = episodes[~episodes.task.str.startswith("random_")]
    assert profile_curves(paper_only, n_boot=N_BOOT) == {}
    assert performance_profiles(paper_only, n_boot=N_BOOT) is None
    assert performance_profiles(episodes.iloc[0:0], n_boot=N_BOOT) is None
