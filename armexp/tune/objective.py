"""The CSO objective: time-domain criteria of the closed-loop tracking error (DESIGN §5).

**Scenarios.** A fixed, seeded set of S reference scenarios "of the kind the agent produces":
q_d(0) drawn uniformly in the middle 60 % of each joint's range, q(0) = q_d(0) + offset with the
offset's sign drawn per joint (magnitude ``offset`` rad), q̇_d uniform within the robot's velocity
bounds and redrawn every ``switch_period`` (30 ms), for ``horizon`` seconds, with the plant's F
and τ_d active (each scenario has its own τ_d seed). Every candidate sees the same scenarios.

**Criteria.** Per scenario and joint j, on the normalised error ε(t) = e1_j(t) / e1_j(0), which
starts at 1 and should decay to 0:

* overshoot M_p = max(0, −min_t ε(t)): how far the error swings past zero (fraction of offset);
* rise time t_r: time from the first ε ≤ ``rise_high`` (0.9) to the first ε ≤ ``rise_low``
  (0.1), in s (the horizon when the error never gets there);
* settling time t_s: the earliest time after which |ε| ≤ ``settle_band`` (2 %) until the end of
  the horizon, in s (the horizon when it ends outside the band);
* steady-state error E_ss: mean |ε| over the last ``steady_window`` fraction of the horizon.

They combine as Gaing (2004): W = (1 − e^−β)(M_p + E_ss) + e^−β (t_s − t_r), β = ``gaing_beta``
(1), summed over joints and averaged over scenarios. A run that diverges scores +inf.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armexp.sim.core import simulate_batch
from armexp.sim.model import Array, Plant
from armexp.sim.scenario import command_count, hold_steps


@dataclass(frozen=True)
class ObjectiveSettings:
    n_scenarios: int = 8
    horizon: float = 0.6
    switch_period: float = 0.03
    offset: float = 0.05
    seed: int = 2024
    gaing_beta: float = 1.0
    settle_band: float = 0.02
    rise_high: float = 0.9
    rise_low: float = 0.1
    steady_window: float = 0.2


@dataclass(frozen=True)
class ScenarioSet:
    q0: Array  # (S, n) reference start q_d(0)
    offset: Array  # (S, n) q(0) − q_d(0)
    commands: Array  # (S, C, n) held q̇_d
    hold_steps: int
    seeds: Array  # (S,) τ_d seeds

    @property
    def n_steps(self) -> int:
        return int(self.commands.shape[1] * self.hold_steps)


def make_scenarios(
    settings: ObjectiveSettings,
    joint_lower: Array,
    joint_upper: Array,
    velocity_bound: Array,
    dt: float,
) -> ScenarioSet:
    """The seeded scenario set described in the module docstring."""
    rng = np.random.default_rng(settings.seed)
    s = settings.n_scenarios
    n = len(velocity_bound)
    lo = np.asarray(joint_lower, float)
    hi = np.asarray(joint_upper, float)
    mid, half = (lo + hi) / 2, 0.3 * (hi - lo)
    q0 = rng.uniform(mid - half, mid + half, size=(s, n))
    offset = settings.offset * rng.choice([-1.0, 1.0], size=(s, n))
    try:
        hold = hold_steps(settings.switch_period, dt)
    except ValueError:
        raise ValueError(
            f"tuner.objective.switch_period={settings.switch_period} is not allowed: it must be a "
            f"whole number of controller periods ({dt} s)."
        ) from None
    n_cmd = command_count(settings.horizon, hold, dt)
    commands = rng.uniform(-1.0, 1.0, size=(s, n_cmd, n)) * np.asarray(velocity_bound, float)
    seeds = rng.integers(0, 2**31 - 1, size=s).astype(np.float64)
    return ScenarioSet(q0, offset, commands, hold, seeds)


@dataclass(frozen=True)
class Criteria:
    """Per (candidate, scenario, joint) criteria and the per-candidate objective W."""

    overshoot: Array
    rise_time: Array
    settling_time: Array
    steady_state_error: Array
    diverged: Array  # (K, S) bool
    score: Array  # (K,)


def _first_index(mask: np.ndarray) -> np.ndarray:
    """Index of the first True along the last axis, or -1."""
    idx = mask.argmax(axis=-1)
    return np.where(mask.any(axis=-1), idx, -1)


def criteria_from_errors(
    err: Array, offset: Array, dt: float, settings: ObjectiveSettings, completed: Array
) -> Criteria:
    """Criteria from e1 traces ``err`` (K, S, T, n) of runs started at ``offset`` (S, n)."""
    _k, _s, t_len, _n = err.shape
    horizon = t_len * dt
    eps = np.moveaxis(err / offset[None, :, None, :], 2, 3)  # (K, S, n, T)
    diverged = completed < t_len
    eps = np.where(np.isfinite(eps), eps, np.inf)

    overshoot = np.maximum(0.0, -eps.min(axis=-1))
    t_high = _first_index(eps <= settings.rise_high)
    t_low = _first_index(eps <= settings.rise_low)
    rise = np.where((t_high >= 0) & (t_low >= 0), (t_low - t_high) * dt, horizon)
    outside = np.abs(eps) > settings.settle_band
    last_out = t_len - 1 - outside[..., ::-1].argmax(axis=-1)
    settle = np.where(outside.any(axis=-1), (last_out + 1) * dt, 0.0)
    settle = np.where(outside[..., -1], horizon, settle)
    window = max(1, round(settings.steady_window * t_len))
    ess = np.abs(eps[..., -window:]).mean(axis=-1)

    w_mp = 1.0 - np.exp(-settings.gaing_beta)
    w_t = np.exp(-settings.gaing_beta)
    w = w_mp * (overshoot + ess) + w_t * (settle - rise)
    per_scenario = w.sum(axis=-1)  # (K, S)
    per_scenario = np.where(diverged | ~np.isfinite(per_scenario), np.inf, per_scenario)
    score = per_scenario.mean(axis=-1)
    return Criteria(overshoot, rise, settle, ess, diverged, score)


class TuningObjective:
    """Callable for `cuckoo_search`: (K, p) gain candidates → K values of W (lower is better).

    Candidates are simulated together by the compiled, parallel `simulate_batch`.
    """

    def __init__(
        self, plant: Plant, kind: int, scenarios: ScenarioSet, settings: ObjectiveSettings
    ) -> None:
        self.plant = plant
        self.kind = kind
        self.scenarios = scenarios
        self.settings = settings
        self._model = plant.packed()
        self.n_calls = 0

    def simulate(self, candidates: Array) -> tuple[Array, np.ndarray]:
        """e1 traces (K, S, T, n) and completed step counts (K, S) for the candidates."""
        sc = self.scenarios
        cand = np.ascontiguousarray(np.atleast_2d(candidates), dtype=np.float64)
        err = np.empty((cand.shape[0], sc.q0.shape[0], sc.n_steps, sc.q0.shape[1]))
        done = simulate_batch(
            self.kind,
            cand,
            sc.q0,
            sc.offset,
            sc.commands,
            sc.hold_steps,
            self._model,
            self.plant.dt,
            sc.seeds,
            err,
        )
        return err, done

    def criteria(self, candidates: Array) -> Criteria:
        err, done = self.simulate(candidates)
        return criteria_from_errors(err, self.scenarios.offset, self.plant.dt, self.settings, done)

    def __call__(self, candidates: Array) -> Array:
        self.n_calls += 1
        return self.criteria(candidates).score
