"""The CSO objective: time-domain criteria of the closed-loop tracking error (docs/design.md §5).

**Scenarios.** A fixed, seeded set of S reference scenarios "of the kind the agent produces":
q_d(0) drawn uniformly in the middle 60 % of each joint's range — except a ``straight_share`` of
them, which start with joints 2..n at 0 (the straight arm, where M(q)⁻¹ is largest) — q(0) =
q_d(0) + offset with the offset's sign drawn per joint (magnitude ``offset`` rad), velocity
commands uniform within the robot's bounds, redrawn every ``switch_period`` (30 ms) and fed
through the reference generator (`armexp.sim.step.REFERENCES`), for ``horizon`` seconds, with the
plant's F and τ_d active (each scenario has its own τ_d seed). Every candidate sees the same
scenarios.

**Criteria.** Per scenario and joint j, on the normalised error ε(t) = e1_j(t) / e1_j(0), which
starts at 1 and should decay to 0:

* overshoot M_p = max(0, −min_t ε(t)): how far the error swings past zero (fraction of offset);
* rise time t_r: time from the first ε ≤ ``rise_high`` (0.9) to the first ε ≤ ``rise_low``
  (0.1), in s (the horizon when the error never gets there);
* settling time t_s: the earliest time after which |ε| ≤ ``settle_band`` (2 %) until the end of
  the horizon, in s (the horizon when it ends outside the band);
* steady-state error E_ss: mean |ε| over the last ``steady_window`` fraction of the horizon.

**Criterion** (``criterion``, docs/design.md §5), J per scenario, summed over joints and averaged
over scenarios:

* ``gaing`` (the paper's): W = (1 − e^−β)(M_p + E_ss) + e^−β (t_s − t_r), β = ``gaing_beta`` (1)
  (Gaing 2004). When a joint does not settle within the horizon, t_s is the horizon and W then
  rewards the slowest rise: at short horizons it starves a PID of integral action, whose error
  decays over seconds. Its default horizon is the paper's 0.6 s.
* ``itae``: ∫ t |ε(t)| dt, the integral of time-weighted absolute error (s²), which weighs a
  lingering error more the later it is; default horizon 1.5 s, long enough for integral action.
* ``iae``: ∫ |ε(t)| dt (s), default horizon 1.5 s.

A run that diverges scores +inf.

**Constraints** (docs/design.md §5). No criterion sees what makes gains unusable, so the score is

    score = J · (1 + effort_weight · P + saturation_weight · L)  (stable candidates)
    score = +inf                                                  (otherwise)

(a relative penalty, so its weight means the same under every criterion's scale):

* stability: the sampled loop with every gain × ``gain_margin`` must be stable at every pose of
  `armexp.tune.stability.pose_grid` (``stability_points`` per joint, the straight arm
  included); such candidates are not simulated. For the adaptive law the loop is checked again
  after the simulation with its adaptive term b1 ρ̂ frozen at the largest value the scenarios
  reached (``sigma_max``), so adaptation cannot carry the loop past the sampling limit.
  ``gain_margin: null`` drops the constraint.
* effort while tracking, with the plant's torque limits: over the part of each scenario after
  ``effort_from`` × horizon (the offset is removed by then; removing it may need the limit),
  P is the peak of max_j |τ_j| / limit_j and L the fraction of steps with some joint at its
  limit, both averaged over the scenarios. Without limits both are 0. ``peak_torque`` reports
  the peak over the whole run.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armexp.sim.controllers import ADAPTIVE
from armexp.sim.model import Array, Plant
from armexp.sim.scenario import command_count, hold_steps
from armexp.sim.simulator import simulate_batch
from armexp.tune import stability

#: The tuning criteria and their default horizons (s): the paper's 0.6 s for Gaing's W; 1.5 s for
#: the integral criteria, long enough for a PID's integral action to act.
CRITERIA = {"gaing": 0.6, "itae": 1.5, "iae": 1.5}


def resolved_horizon(criterion: str, horizon: float | None) -> float:
    """The scenarios' length (s): ``horizon`` when set, else the criterion's default."""
    if criterion not in CRITERIA:
        raise ValueError(
            f"tuner.objective.criterion={criterion} is not allowed: choose one of "
            f"{', '.join(CRITERIA)}."
        )
    return float(CRITERIA[criterion] if horizon is None else horizon)


@dataclass(frozen=True)
class ObjectiveSettings:
    n_scenarios: int = 8
    horizon: float = 0.6
    criterion: str = "gaing"
    switch_period: float = 0.03
    offset: float = 0.05
    seed: int = 2024
    gaing_beta: float = 1.0
    settle_band: float = 0.02
    rise_high: float = 0.9
    rise_low: float = 0.1
    steady_window: float = 0.2
    straight_share: float = 0.25
    gain_margin: float | None = 1.25
    stability_points: int = 9
    effort_weight: float = 0.1
    saturation_weight: float = 1.0
    effort_from: float = 0.5


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
    straight = round(settings.straight_share * s)
    q0[:straight, 1:] = np.clip(0.0, lo[1:], hi[1:])
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
    #: Per (candidate, scenario, joint): ∫ t|ε| dt and ∫ |ε| dt.
    itae: Array
    iae: Array
    diverged: Array  # (K, S) bool
    score: Array  # (K,)
    #: Per candidate: the criterion J before the effort penalty (mean over scenarios).
    criterion: Array
    #: Per candidate: peak max_j |τ_j| (N·m, max over scenarios), mean peak |τ_j| / limit_j and
    #: mean fraction of steps at the limit (over scenarios), and the stability constraint met.
    peak_torque: Array
    peak_ratio: Array
    time_at_limit: Array
    stable: Array
    #: Per candidate: the largest adaptive term b1 ρ̂ over the scenarios (0 for other laws).
    sigma_max: Array


def _first_index(mask: np.ndarray) -> np.ndarray:
    """Index of the first True along the last axis, or -1."""
    idx = mask.argmax(axis=-1)
    return np.where(mask.any(axis=-1), idx, -1)


def _time_domain(
    eps: Array, dt: float, settings: ObjectiveSettings
) -> tuple[Array, Array, Array, Array, Array]:
    """M_p, t_r, t_s, E_ss and Gaing's W per (candidate, scenario, joint) of ε (K, S, n, T)."""
    t_len = eps.shape[-1]
    horizon = t_len * dt
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
    return overshoot, rise, settle, ess, w


def criteria_from_errors(
    err: Array,
    offset: Array,
    dt: float,
    settings: ObjectiveSettings,
    completed: np.ndarray,
    torque: Array | None = None,
    limit: Array | None = None,
    stable: Array | None = None,
    sigma_max: Array | None = None,
    time_domain: bool = True,
) -> Criteria:
    """Criteria from e1 traces ``err`` (K, S, T, n) of runs started at ``offset`` (S, n), with
    the applied ``torque`` (K, S, T, n) against ``limit`` (n,) for the effort term, the
    stability verdict ``stable`` (K,) and the adaptive term's peak ``sigma_max`` (K,) (see the
    module docstring). Without ``time_domain`` the Gaing terms (M_p, t_r, t_s, E_ss) are left
    NaN unless the criterion needs them: the search scores thousands of candidates by one
    criterion."""
    k_len, s_len, t_len, n = err.shape
    diverged = completed < t_len
    # ε (K, S, T, n); a diverged run's NaN tail counts as an infinite error.
    eps = err / offset[None, :, None, :]
    eps = np.where(np.isfinite(eps), eps, np.inf)
    # Capped so that inf never meets t = 0 (inf · 0): diverged runs score inf below anyway.
    magnitude = np.minimum(np.abs(eps), 1e300)
    t = np.arange(t_len) * dt
    iae = magnitude.sum(axis=2) * dt
    itae = np.einsum("kstj,t->ksj", magnitude, t) * dt
    if time_domain or settings.criterion == "gaing":
        overshoot, rise, settle, ess, w = _time_domain(np.moveaxis(eps, 2, 3), dt, settings)
    else:
        overshoot = rise = settle = ess = w = np.full((k_len, s_len, n), np.nan)
    per_joint = {"gaing": w, "itae": itae, "iae": iae}[settings.criterion]
    per_scenario = per_joint.sum(axis=-1)  # (K, S)
    per_scenario = np.where(diverged | ~np.isfinite(per_scenario), np.inf, per_scenario)
    criterion = per_scenario.mean(axis=-1)

    stable = np.ones(k_len, bool) if stable is None else stable
    peak = np.zeros(k_len)
    ratio = np.zeros(k_len)
    at_limit = np.zeros(k_len)
    if torque is not None:
        mag = np.nan_to_num(np.abs(torque), nan=0.0)
        peak = mag.max(axis=(1, 2, 3))
        lim = np.full(n, np.inf) if limit is None else np.asarray(limit, float)
        if np.isfinite(lim).all():
            tracking = mag[:, :, round(settings.effort_from * t_len) :]
            ratio = (tracking / lim).max(axis=(2, 3)).mean(axis=1)
            at_limit = (tracking >= lim).any(axis=3).mean(axis=2).mean(axis=1)
    penalty = settings.effort_weight * ratio + settings.saturation_weight * at_limit
    score = criterion * (1.0 + penalty)
    score = np.where(stable, score, np.inf)
    sigma = np.zeros(k_len) if sigma_max is None else sigma_max
    return Criteria(
        overshoot, rise, settle, ess, itae, iae, diverged, score, criterion, peak, ratio,
        at_limit, stable, sigma,
    )  # fmt: skip


class TuningObjective:
    """Callable for `cuckoo_search`: (K, p) gain candidates → K values of W (lower is better).

    Candidates are simulated together by the compiled, parallel `simulate_batch`.
    """

    def __init__(
        self,
        plant: Plant,
        kind: int,
        scenarios: ScenarioSet,
        settings: ObjectiveSettings,
        poses: Array,
        ramp: bool = True,
    ) -> None:
        self.plant = plant
        self.kind = kind
        self.scenarios = scenarios
        self.settings = settings
        self.ramp = ramp
        self.linearised = stability.linearise(plant, poses)
        self._model = plant.packed()
        self.n_calls = 0

    def stable(self, candidates: Array, sigma: Array | None = None) -> Array:
        """The stability constraint (K,) of the module docstring (the adaptive term at
        ``sigma``, default 0)."""
        cand = np.atleast_2d(candidates)
        if self.settings.gain_margin is None:
            return np.ones(cand.shape[0], bool)
        return stability.stable_with_margin(
            self.kind, cand, self.linearised, self.settings.gain_margin, sigma
        )

    def gain_margin(self, gains: Array, sigma: float | None = None) -> float:
        """The gain margin of one gain vector over the pose grid (adaptive term at ``sigma``)."""
        return stability.gain_margin(self.kind, gains, self.linearised, sigma=sigma)

    def simulate(self, candidates: Array) -> tuple[Array, np.ndarray]:
        """Traces (K, S, T, 2n + 1) — e1, the applied τ, ρ̂ — and completed step counts (K, S)."""
        sc = self.scenarios
        cand = np.ascontiguousarray(np.atleast_2d(candidates), dtype=np.float64)
        trace = np.empty((cand.shape[0], sc.q0.shape[0], sc.n_steps, 2 * sc.q0.shape[1] + 1))
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
            trace,
            self.ramp,
        )
        return trace, done

    def criteria(self, candidates: Array, time_domain: bool = True) -> Criteria:
        """Criteria of every candidate; unstable ones are not simulated (they score +inf), and
        an adaptive candidate unstable at the largest adaptive term it reached scores +inf."""
        cand = np.atleast_2d(np.asarray(candidates, dtype=np.float64))
        sc = self.scenarios
        n = sc.q0.shape[1]
        stable = self.stable(cand)
        trace = np.full((cand.shape[0], sc.q0.shape[0], sc.n_steps, 2 * n + 1), np.nan)
        done = np.zeros((cand.shape[0], sc.q0.shape[0]), dtype=np.int64)
        sigma = np.zeros(cand.shape[0])
        if stable.any():
            trace[stable], done[stable] = self.simulate(cand[stable])
            if self.kind == ADAPTIVE:
                rho = trace[stable, :, :, 2 * n]
                peak = np.where(np.isfinite(rho), rho, 0.0).max(axis=(1, 2))
                sigma[stable] = cand[stable, 2] * np.maximum(peak, 0.0)
                stable[stable] = self.stable(cand[stable], sigma[stable])
        return criteria_from_errors(
            trace[..., :n], sc.offset, self.plant.dt, self.settings, done,
            torque=trace[..., n : 2 * n], limit=self.plant.torque_limit, stable=stable,
            sigma_max=sigma, time_domain=time_domain,
        )  # fmt: skip

    def __call__(self, candidates: Array) -> Array:
        self.n_calls += 1
        return self.criteria(candidates, time_domain=False).score
