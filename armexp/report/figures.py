"""The paper's figures from stored trajectories and metric histories (PNG and PDF).

* Fig. 3: tip paths of tasks (a)–(d) with the obstacles, targets and the arm's initial pose;
* Fig. 4: tip-to-target error against time;
* Fig. 5: joint torques against time, one column per controller label (the proposed control and
  each baseline), the same scale along each row;
* Fig. 6: joint position tracking (reference q_d vs actual q) with a zoom on the first 0.1 s, one
  pair of columns per label (the report draws the proposed control and its main baseline: the
  reference differs between controllers, because the policy answers each closed loop, so every
  panel shows its own q_d);
* learning curves (success rate and episode reward against environment steps) and CSO
  convergence (best objective per iteration).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import pandas as pd

COLORS = {"a": "#1f77b4", "b": "#ff7f0e", "c": "#2ca02c", "d": "#d62728"}
# No timestamps in the files, so the same data gives the same bytes.
_PDF_META = {"CreationDate": None, "ModDate": None, "Producer": "armexp", "Creator": "armexp"}


def save(fig: Any, folder: Path, name: str) -> list[Path]:
    paths = [folder / f"{name}.png", folder / f"{name}.pdf"]
    fig.savefig(paths[0], dpi=130, bbox_inches="tight", metadata={"Software": "armexp"})
    fig.savefig(paths[1], bbox_inches="tight", metadata=_PDF_META)
    plt.close(fig)
    return paths


def tip_paths(
    trajectories: dict[str, pd.DataFrame],
    targets: dict[str, tuple[float, float]],
    obstacles: list[dict[str, float]],
    lengths: list[float],
    q0: list[float],
    threshold: float,
) -> Any:
    fig, ax = plt.subplots(figsize=(6.2, 6.0))
    for ob in obstacles:
        ax.add_patch(plt.Circle((ob["x"], ob["y"]), ob["r"], color="#d9534f", alpha=0.55, lw=0))
    th = np.cumsum(q0)
    joints = np.vstack(
        [
            [0.0, 0.0],
            np.cumsum(
                np.c_[np.multiply(lengths, np.cos(th)), np.multiply(lengths, np.sin(th))], axis=0
            ),
        ]
    )
    ax.plot(joints[:, 0], joints[:, 1], "-o", color="0.35", lw=3, ms=5, label="arm at start")
    for task, frame in trajectories.items():
        c = COLORS.get(task)
        ax.plot(frame.tip_x, frame.tip_y, color=c, lw=1.6, label=f"({task})")
        target = targets[task]
        ax.add_patch(plt.Circle(target, threshold, fill=False, color=c, lw=1))
        ax.plot(*target, "*", color=c, ms=12)
        ax.annotate(f"({task})", target, textcoords="offset points", xytext=(6, 6), color=c)
    reach = float(sum(lengths))
    ax.set_xlim(-reach - 0.1, reach + 0.1)
    ax.set_ylim(-reach - 0.1, reach + 0.1)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("Fig. 3: tip paths with obstacles (proposed control)")
    ax.legend(loc="lower left", fontsize=8)
    return fig


def target_error(trajectories: dict[str, pd.DataFrame], threshold: float) -> Any:
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for task, frame in trajectories.items():
        ax.plot(frame.t, frame.target_error, color=COLORS.get(task), label=f"({task})")
    ax.axhline(threshold, color="0.3", ls="--", lw=1, label=f"threshold {threshold:g} m")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("tip-to-target error (m)")
    ax.set_title("Fig. 4: target error (proposed control)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return fig


def torques(trajectories: dict[str, dict[str, pd.DataFrame]]) -> Any:
    """Fig. 5: ``trajectories[label][task]``; rows are joints, columns labels (the first one
    is the proposed control), tasks by colour."""
    columns = {label: frames for label, frames in trajectories.items() if frames}
    n = _joints(next(iter(next(iter(columns.values())).values())))
    width = 7 if len(columns) == 1 else 3.6 * len(columns)
    fig, axes = plt.subplots(
        n, len(columns), figsize=(width, 2.4 * n), sharex=True, sharey="row", squeeze=False
    )
    for col, (label, frames) in enumerate(columns.items()):
        for j in range(n):
            ax = axes[j, col]
            for task, frame in frames.items():
                ax.plot(frame.t, frame[f"tau_{j + 1}"], color=COLORS.get(task), lw=0.8,
                        label=f"({task})")  # fmt: skip
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(f"τ{j + 1} (N·m)")
        axes[0, col].set_title(label, fontsize=9)
        axes[-1, col].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8, ncol=4)
    names = " and ".join(columns) if len(columns) <= 2 else ", ".join(columns)
    fig.suptitle(f"Fig. 5: joint torques ({names})")
    fig.tight_layout()
    return fig


def tracking(frames: dict[str, pd.DataFrame], task: str, zoom: float = 0.1) -> Any:
    """Fig. 6: ``frames[label]`` of one task; per label a full and a zoomed column, each panel
    with that label's own reference q_d."""
    n = _joints(next(iter(frames.values())))
    k = len(frames)
    fig, axes = plt.subplots(n, 2 * k, figsize=(4.5 * k + 4.5 * (k == 1), 2.5 * n),
                             gridspec_kw={"width_ratios": [3, 1] * k}, squeeze=False)  # fmt: skip
    for i, (label, frame) in enumerate(frames.items()):
        early = frame[frame.t <= frame.t.iloc[0] + zoom]
        color = COLORS.get(task, "C0") if i == 0 else f"C{i + 4}"
        for j in range(n):
            for ax, part in ((axes[j, 2 * i], frame), (axes[j, 2 * i + 1], early)):
                ax.plot(part.t, part[f"q_d_{j + 1}"], "k--", lw=1.2, label="reference q_d")
                ax.plot(part.t, part[f"q_{j + 1}"], color=color, lw=1, label="actual q")
                ax.grid(alpha=0.3)
            if i == 0:
                axes[j, 0].set_ylabel(f"q{j + 1} (rad)")
        axes[0, 2 * i].set_title(label, fontsize=9)
        axes[0, 2 * i + 1].set_title(f"first {zoom:g} s", fontsize=9)
        axes[-1, 2 * i].set_xlabel("t (s)")
        axes[-1, 2 * i + 1].set_xlabel("t (s)")
    axes[0, 0].legend(fontsize=8)
    fig.suptitle(f"Fig. 6: joint position tracking, task ({task})")
    fig.tight_layout()
    return fig


def learning_curves(curves: dict[str, dict[str, pd.DataFrame]]) -> Any:
    """``curves[label]`` holds ``success`` (rolling 100), ``reward`` (per episode) and optionally
    ``held_out`` (deterministic policy on held-out targets) histories against steps."""
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for i, (label, c) in enumerate(curves.items()):
        color = f"C{i}"
        if len(c.get("success", [])):
            top.plot(
                c["success"].step,
                c["success"].value,
                color=color,
                label=f"{label}: training (last 100 episodes)",
            )
        if len(c.get("held_out", [])):
            top.plot(
                c["held_out"].step,
                c["held_out"].value,
                "o--",
                color=color,
                ms=4,
                label=f"{label}: held-out targets",
            )
        if len(c.get("reward", [])):
            r = c["reward"]
            window = max(1, min(50, len(r) // 10))
            bottom.plot(
                r.step, r.value.rolling(window, min_periods=1).mean(), color=color, label=label
            )
    top.set_ylabel("success rate")
    top.set_ylim(-0.02, 1.02)
    top.grid(alpha=0.3)
    if top.get_legend_handles_labels()[0]:
        top.legend(fontsize=7)
    else:  # a budget too short to finish an episode or reach a held-out check
        top.text(0.5, 0.5, "no finished episodes or held-out checks", ha="center",
                 va="center", transform=top.transAxes, fontsize=8)  # fmt: skip
    bottom.set_ylabel("episode reward (rolling mean)")
    bottom.set_xlabel("environment steps")
    bottom.grid(alpha=0.3)
    fig.suptitle("Learning curves")
    return fig


def cso_convergence(histories: dict[str, pd.DataFrame], paper: dict[str, float]) -> Any:
    """Best objective per CSO iteration of each tune run (``histories`` by label), with the
    paper's gains' objective where given (``paper`` by the same labels)."""
    fig, ax = plt.subplots(figsize=(7, 3.8))
    for i, (label, h) in enumerate(histories.items()):
        ax.plot(h.step, h.value, color=f"C{i}", label=label)
        ref = paper.get(label, math.nan)
        if math.isfinite(ref):
            ax.axhline(ref, color=f"C{i}", ls=":", lw=1, label=f"{label}: paper's gains")
    ax.set_yscale("log")
    ax.set_xlabel("CSO iteration")
    ax.set_ylabel("best objective (each run's criterion)")
    ax.set_title("Cuckoo search convergence")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    return fig


def _joints(frame: pd.DataFrame) -> int:
    return sum(1 for c in frame.columns if c.startswith("tau_"))
