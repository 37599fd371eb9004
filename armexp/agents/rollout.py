"""Running a trained policy on one episode and measuring it (docs/design.md §8, Table III)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armexp.envs.reach import ReachEnv
from armexp.sim.convergence import definition_one
from armexp.sim.metrics import tracking_metrics
from armexp.sim.model import Array


@dataclass
class Episode:
    """One evaluated episode: how it ended, its return, and the 1 kHz rows (with target error)."""

    reason: str
    steps: int
    episode_return: float
    final_error: float
    target: Array
    rows: Array


def rollout(
    env: ReachEnv,
    policy: Any,
    options: dict[str, Any],
    seed: int,
    deterministic: bool = True,
    max_steps: int | None = None,
) -> Episode:
    """Run ``policy`` (anything with SB3's ``predict``) for one episode of ``env``, or for its
    first ``max_steps`` actions."""
    obs, info = env.reset(seed=seed, options=options)
    total = 0.0
    while True:
        action, _ = policy.predict(obs, deterministic=deterministic)
        obs, reward, terminated, truncated, info = env.step(action)
        total += reward
        if terminated or truncated or (max_steps is not None and info["steps"] >= max_steps):
            break
    rows = env.trajectory() if env.record else np.zeros((0, 0))
    return Episode(
        info["reason"], int(info["steps"]), total, float(info["tip_error"]), env.target.copy(), rows
    )


def episode_metrics(episode: Episode, n: int, lengths: Array, threshold: float) -> dict[str, float]:
    """Table III's quantities for one episode that starts with zero tracking error.

    success, target_time (s, first time the tip error < threshold; NaN if never),
    final_error_cm, rms_e1 (rad) and tip_rms_cm (tracking), max_abs_tau_<j> (N·m),
    time_at_limit (s with some joint at its torque limit), collision, steps, return. The
    convergence columns come from perturbed runs instead (`convergence_metrics`).
    """
    rows = episode.rows
    t = rows[:, 0]
    error = rows[:, -1]
    inside = np.nonzero(error < threshold)[0]
    tracking = tracking_metrics(rows[:, :-1], n, lengths)
    out = {
        "success": float(episode.reason == "reached"),
        "collision": float(episode.reason == "collision"),
        "target_time": _target_time(t, inside, episode.reason == "reached"),
        "final_error_cm": episode.final_error * 100.0,
        "rms_e1": tracking["rms_e1"],
        "tip_rms_cm": tracking["tip_rms_cm"],
        "time_at_limit": tracking["time_at_limit"],
        "steps": float(episode.steps),
        "return": float(episode.episode_return),
        "duration": float(t[-1] - t[0]) if t.size else 0.0,
    }
    for j in range(1, n + 1):
        out[f"max_abs_tau_{j}"] = tracking[f"max_abs_tau_{j}"]
    return out


def convergence_metrics(
    episode: Episode, n: int, offset: float, window: float, tolerance: float
) -> dict[str, float]:
    """Convergence from a defined perturbation (docs/design.md §8), on a run started with the
    reference ``offset`` rad from the arm on every joint: Definition 1's decay rate, ultimate
    bound and overshoot, the ‖e1‖ settling time and ITAE over its first ``window`` s
    (`armexp.sim.convergence.definition_one`)."""
    rows = episode.rows
    if rows.size == 0:
        return definition_one(np.zeros(0), np.zeros(0), offset, window, tolerance)
    e1 = rows[:, 1 : 1 + n] - rows[:, 1 + n : 1 + 2 * n]
    return definition_one(rows[:, 0], np.linalg.norm(e1, axis=1), offset, window, tolerance)


def _target_time(t: Array, inside: np.ndarray, reached: bool) -> float:
    """First logged time inside the threshold; a reach that happens during the very last
    controller step is only seen at the end of it (rows hold each step's start)."""
    if inside.size:
        return float(t[inside[0]])
    if reached and t.size >= 2:
        return float(t[-1] + (t[1] - t[0]))
    return float("nan")
