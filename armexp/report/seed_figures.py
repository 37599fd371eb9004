"""Seed-level figures with robust statistics across runs (Agarwal et al., NeurIPS 2021).

* :func:`curve_band` / :func:`learning_curves_ci`: IQM learning curves across seeds with a 95 %
  stratified percentile bootstrap band (one stratum per checked step);
* :func:`profile_curves` / :func:`performance_profiles`: performance profiles on the held-out
  targets, of the per-run success rate and of the per-episode tip tracking error.

Data come as plain frames (histories and per-episode evaluation rows); nothing here simulates.
"""

from __future__ import annotations

import math

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import numpy.typing as npt
import pandas as pd
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from armexp.report import episodes as episode_tables
from armexp.report import stats

BAND_COLUMNS = ["step", "iqm", "low", "high", "runs"]
PROFILE_COLUMNS = ["tau", "fraction", "low", "high"]
HELD_OUT_PREFIX = "random_"
SUCCESS_THRESHOLDS = np.linspace(0.0, 1.0, 101)
N_TRACKING_THRESHOLDS = 100

Array = npt.NDArray[np.float64]


def _clean(history: pd.DataFrame) -> pd.Series:
    """``value`` against sorted unique ``step`` (duplicate steps averaged, NaN rows dropped)."""
    if len(history) == 0:
        return pd.Series(dtype=np.float64)
    h = history[["step", "value"]].dropna()
    return h.groupby("step", sort=True)["value"].mean().astype(np.float64)


def curve_band(histories: list[pd.DataFrame], n_boot: int = 2000, seed: int = 0) -> pd.DataFrame:
    """IQM across runs of ``step``/``value`` histories, with a 95 % bootstrap band.

    The step grid is the union of all runs' steps up to the smallest last step (so every run
    covers it); each run is linearly interpolated onto the grid (``np.interp``; before a run's
    first step its first value is held). The band is the stratified percentile bootstrap of the
    per-step IQM over the ``(runs, steps)`` matrix (runs resampled within each step). Histories
    with no points are ignored; with a single run the band is NaN. Columns: ``step``, ``iqm``,
    ``low``, ``high``, ``runs``.
    """
    runs = [s for s in (_clean(h) for h in histories) if len(s)]
    if not runs:
        return pd.DataFrame({c: pd.Series(dtype=np.float64) for c in BAND_COLUMNS})
    last = min(s.index[-1] for s in runs)
    grid = np.unique(np.concatenate([s.index.to_numpy() for s in runs]))
    grid = grid[grid <= last]
    x = grid.astype(np.float64)
    matrix = np.stack(
        [np.interp(x, s.index.to_numpy(dtype=np.float64), s.to_numpy()) for s in runs]
    )
    if len(runs) == 1:
        point: Array = matrix[0]
        low = high = np.full(len(grid), np.nan)
    else:
        point, low, high = stats.iqm_columns_ci(matrix, n_boot=n_boot, seed=seed)
    return pd.DataFrame(
        {"step": grid, "iqm": point, "low": low, "high": high, "runs": len(runs)},
        columns=BAND_COLUMNS,
    )


def _seeds(n: int) -> str:
    return f"{n} seed" if n == 1 else f"{n} seeds"


def _band(ax: Axes, x: npt.ArrayLike, low: pd.Series, high: pd.Series, color: str) -> None:
    """Shade ``[low, high]`` unless the band is NaN throughout (one run)."""
    if low.notna().any():
        ax.fill_between(x, low.to_numpy(), high.to_numpy(), color=color, alpha=0.2, lw=0)


def learning_curves_ci(groups: dict[str, list[pd.DataFrame]], n_boot: int = 2000) -> Figure:
    """One IQM held-out success curve per group (label → one history per seed) against
    environment steps, shaded with its 95 % bootstrap band where a group has several runs."""
    fig, ax = plt.subplots(figsize=(7, 4))
    for i, (label, histories) in enumerate(groups.items()):
        band = curve_band(histories, n_boot=n_boot)
        if band.empty:
            continue
        color = f"C{i}"
        n = int(band["runs"].iloc[0])
        ax.plot(band["step"], band["iqm"], color=color, label=f"{label}, {_seeds(n)}")
        if n > 1:
            _band(ax, band["step"], band["low"], band["high"], color)
    ax.set_ylim(-0.02, 1.02)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("held-out success (IQM across seeds)")
    ax.set_title("Learning curves: IQM and 95 % bootstrap CI across seeds")
    ax.grid(alpha=0.3)
    if ax.get_lines():
        ax.legend(fontsize=8)
    return fig


def _profile(scores: Array, thresholds: Array, higher_is_better: bool, n_boot: int) -> pd.DataFrame:
    if scores.shape[0] > 1:
        p, lo, hi = stats.performance_profile_ci(
            scores, thresholds, higher_is_better=higher_is_better, n_boot=n_boot
        )
    else:
        p = stats.performance_profile(scores, thresholds, higher_is_better)
        lo = hi = np.full(len(thresholds), np.nan)
    return pd.DataFrame(
        {"tau": thresholds, "fraction": p, "low": lo, "high": hi}, columns=PROFILE_COLUMNS
    )


def _held_out(episodes: pd.DataFrame) -> pd.DataFrame:
    if episodes.empty or "task" not in episodes.columns:
        return episodes.iloc[0:0]
    return episodes[episodes["task"].astype(str).str.startswith(HELD_OUT_PREFIX)]


def profile_curves(
    episodes: pd.DataFrame, n_boot: int = 2000
) -> dict[str, dict[str, pd.DataFrame]]:
    """Performance profiles on the held-out rows (``task`` starting with ``random_``).

    Keyed by series ``f"{agent}, {controller}"`` (sorted), each with two frames of columns
    ``tau``, ``fraction``, ``low``, ``high``:

    * ``"success"``: fraction of eval runs whose mean held-out success is > τ, τ in
      ``linspace(0, 1, 101)``;
    * ``"tracking"``: fraction of held-out episodes (eval run × target, targets missing for some
      run dropped) with ``tip_rms_cm`` < τ, τ on a 100-point geometric grid shared by all series
      from the smallest to just above the largest positive finite error (so every profile reaches
      1 at its last τ), the band resampling runs within each target.

    Bands are 95 % stratified percentile bootstraps, NaN for a series with a single eval run.
    """
    held = _held_out(episodes)
    if held.empty:
        return {}
    success: dict[str, Array] = {}
    tracking: dict[str, Array] = {}
    for (agent, controller), g in held.groupby(["agent", "controller"], sort=True):
        key = f"{agent}, {controller}"
        per_run = g.groupby("eval_run", sort=True)["success"].mean()
        success[key] = per_run.to_numpy(dtype=np.float64)
        table = g.pivot_table(
            index="eval_run", columns="task", values="tip_rms_cm", aggfunc="mean", dropna=False
        )
        tracking[key] = table.dropna(axis=1, how="any").to_numpy(dtype=np.float64)
    pooled = np.concatenate([m.ravel() for m in tracking.values()])
    pooled = pooled[np.isfinite(pooled) & (pooled > 0)]
    taus: Array | None = None
    if pooled.size:
        lo_tau, hi_tau = float(pooled.min()), float(pooled.max())
        taus = np.geomspace(lo_tau, hi_tau, N_TRACKING_THRESHOLDS)
        taus[-1] = np.nextafter(hi_tau, math.inf)  # strict "<": count the largest error too
    empty = pd.DataFrame({c: pd.Series(dtype=np.float64) for c in PROFILE_COLUMNS})
    out: dict[str, dict[str, pd.DataFrame]] = {}
    for key, scores in success.items():
        m = tracking[key]
        out[key] = {
            "success": _profile(scores[:, None], SUCCESS_THRESHOLDS, True, n_boot),
            "tracking": (
                _profile(m, taus, False, n_boot) if taus is not None and m.size else empty.copy()
            ),
        }
    return out


def series_names(episodes: pd.DataFrame) -> dict[str, str]:
    """Legend entries of :func:`profile_curves`' series keys: the agent by its short name
    (`armexp.report.episodes.agent_names`; with one agent, its preset) rather than its label,
    whose description of the agent's aids would widen the legend past the panels."""
    held = _held_out(episodes)
    if held.empty or "agent" not in held.columns:
        return {}
    short = episode_tables.agent_names(held)
    names = {}
    for (agent, controller), g in held.groupby(["agent", "controller"], sort=True):
        name = short.get(agent) or str(g.iloc[0].get("agent_preset", agent))
        names[f"{agent}, {controller}"] = f"{name}, {controller}"
    return names


def performance_profiles(episodes: pd.DataFrame, n_boot: int = 2000) -> Figure | None:
    """Two panels of :func:`profile_curves`: held-out success (left) and tip tracking error
    (right, log τ), one colour per series, adaptive solid and PID dashed; None without held-out
    rows."""
    curves = profile_curves(episodes, n_boot=n_boot)
    if not curves:
        return None
    names = series_names(episodes)
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    for i, (key, c) in enumerate(curves.items()):
        color = f"C{i}"
        style = "-" if key.endswith(", adaptive") else "--"
        for ax, frame in ((left, c["success"]), (right, c["tracking"])):
            if frame.empty:
                continue
            ax.plot(frame["tau"], frame["fraction"], style, color=color, label=names.get(key, key))
            _band(ax, frame["tau"], frame["low"], frame["high"], color)
    left.set_title("held-out success")
    left.set_xlabel("success-rate threshold τ")
    left.set_ylabel("fraction of runs with success > τ")
    right.set_title("tracking error")
    right.set_xscale("log")
    right.set_xlabel("tip tracking error τ (cm)")
    right.set_ylabel("fraction of held-out episodes with error < τ")
    for ax in (left, right):
        ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3, which="both")
    if left.get_lines():
        # Below both panels: series names (agent, controller) are too long to sit inside one.
        left.legend(fontsize=8, loc="upper left", bbox_to_anchor=(0.0, -0.18), ncol=2)
    fig.suptitle("Performance profiles (95 % stratified bootstrap bands across seeds)")
    fig.tight_layout()
    return fig
