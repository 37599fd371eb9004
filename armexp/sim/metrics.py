"""Tracking metrics of a logged closed-loop trajectory (`armexp.sim.trajectory.trajectory_columns`).

Definitions (used by `armexp simulate` now and by evaluation's Table III later):

* ``rms_e1``: RMS over time of ‖e1‖ = ‖q − q_d‖ (rad); ``rms_e1_<j>`` per joint.
* ``max_e1_after_convergence``: max ‖e1‖ after the convergence time (rad).
* ``convergence_time``: earliest t after which ‖e1‖ stays within the band
  max(``band_fraction`` · ‖e1(0)‖, ``band_floor``) for the rest of the run (s).
* ``tip_rms_cm`` / ``tip_max_cm``: distance between the tip at q and the tip at q_d (cm).
* ``max_abs_tau_<j>``: max |τ_j| (N·m) of the applied (saturated) torque; ``time_at_limit``:
  seconds with some joint at its torque limit; ``final_e1``: ‖e1‖ at the end; ``final_rho_hat``.
"""

from __future__ import annotations

import numpy as np

from armexp.sim.model import Array

BAND_FRACTION = 0.02
BAND_FLOOR = 1e-3


def forward_tip(q: Array, lengths: Array) -> Array:
    """Tip positions (T, 2) for joint angles q (T, n)."""
    th = np.cumsum(q, axis=1)
    return np.stack([(lengths * np.cos(th)).sum(1), (lengths * np.sin(th)).sum(1)], axis=1)


def convergence_time(t: Array, err: Array, band: float) -> float:
    """Earliest time after which ``err`` ≤ ``band`` until the end (inf if it ends outside)."""
    outside = np.nonzero(err > band)[0]
    if outside.size == 0:
        return float(t[0])
    last = outside[-1]
    return float(t[last + 1]) if last + 1 < t.size else float("inf")


def _step(t: Array) -> float:
    return float(t[1] - t[0]) if t.size > 1 else 0.0


def tracking_metrics(
    rows: Array,
    n: int,
    lengths: Array,
    band_fraction: float = BAND_FRACTION,
    band_floor: float = BAND_FLOOR,
) -> dict[str, float]:
    t = rows[:, 0]
    q = rows[:, 1 : 1 + n]
    qd = rows[:, 1 + n : 1 + 2 * n]
    tau = rows[:, 1 + 4 * n : 1 + 5 * n]
    e1 = q - qd
    norm = np.linalg.norm(e1, axis=1)
    band = max(band_fraction * float(norm[0]), band_floor)
    tc = convergence_time(t, norm, band)
    after = norm[t >= tc] if np.isfinite(tc) else norm
    tip_err = np.linalg.norm(forward_tip(q, lengths) - forward_tip(qd, lengths), axis=1) * 100.0
    out: dict[str, float] = {
        "rms_e1": float(np.sqrt(np.mean(norm**2))),
        "max_e1_after_convergence": float(after.max()),
        "convergence_time": tc,
        "convergence_band": band,
        "tip_rms_cm": float(np.sqrt(np.mean(tip_err**2))),
        "tip_max_cm": float(tip_err.max()),
        "final_e1": float(norm[-1]),
        "final_rho_hat": float(rows[-1, 1 + 5 * n]),
        "time_at_limit": float(rows[:, 4 + 5 * n : 4 + 6 * n].max(axis=1).sum() * _step(t)),
    }
    for j in range(n):
        out[f"rms_e1_{j + 1}"] = float(np.sqrt(np.mean(e1[:, j] ** 2)))
        out[f"max_abs_tau_{j + 1}"] = float(np.abs(tau[:, j]).max())
    return out
