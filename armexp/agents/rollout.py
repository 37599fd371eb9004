"""Running a trained policy on one episode and measuring it (docs/design.md §8, Table III)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from armexp.envs.reach import ReachEnv
from armexp.sim.metrics import BAND_FRACTION, convergence_time, tracking_metrics
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
    convergence column comes from a perturbed run instead (`settling_time`).
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


def settling_time(episode: Episode, n: int, window: float, nominal: Episode | None = None) -> float:
    """Convergence from a defined perturbation (docs/design.md §8), on a run started with the
    reference offset from the arm: the earliest time after which the perturbation's effect on the
    tracking error stays within 2 % of where it started, until ``window`` s.

    The effect is e1 of this run minus e1 of the same episode without the offset (``nominal``:
    same policy, target and disturbance draws), so the controller's steady tracking error, which
    can sit above 2 % of a small offset, is not mistaken for the perturbation. Without
    ``nominal`` it is ‖e1‖ itself. inf when it is outside at the window's end (or the run ended
    before it), NaN when the run started without an offset.
    """
    rows = episode.rows
    t = rows[:, 0]
    if t.size < 2:
        return float("nan")
    e1 = rows[:, 1 : 1 + n] - rows[:, 1 + n : 1 + 2 * n]
    if nominal is not None:
        base = nominal.rows[: t.size]
        if base.shape[0] < t.size:
            return float("inf")
        e1 = e1 - (base[:, 1 : 1 + n] - base[:, 1 + n : 1 + 2 * n])
    norm = np.linalg.norm(e1, axis=1)
    if norm[0] == 0.0:
        return float("nan")
    inside = t < window
    if t[-1] + (t[1] - t[0]) < window - 1e-9:
        return float("inf")
    return convergence_time(t[inside], norm[inside], BAND_FRACTION * float(norm[0]))


def _target_time(t: Array, inside: np.ndarray, reached: bool) -> float:
    """First logged time inside the threshold; a reach that happens during the very last
    controller step is only seen at the end of it (rows hold each step's start)."""
    if inside.size:
        return float(t[inside[0]])
    if reached and t.size >= 2:
        return float(t[-1] + (t[1] - t[0]))
    return float("nan")
