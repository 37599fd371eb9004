"""The CSO objective: criteria on known signals, and tuning results on the real closed loop."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from omegaconf import DictConfig

from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, PID, gain_vector
from armexp.stages.tune import build_objective, search_space
from armexp.tune import cuckoo_search
from armexp.tune.objective import (
    Criteria,
    ObjectiveSettings,
    criteria_from_errors,
    resolved_horizon,
)

DT = 1e-3


def _criteria(trace: np.ndarray, settings: ObjectiveSettings | None = None) -> Criteria:
    err = (0.05 * trace)[None, None, :, None]
    done = np.array([[trace.size]])
    return criteria_from_errors(err, np.array([[0.05]]), DT, settings or ObjectiveSettings(), done)


def test_criteria_of_a_first_order_decay() -> None:
    tau = 0.02
    t = np.arange(600) * DT
    c = _criteria(np.exp(-t / tau), ObjectiveSettings(criterion="gaing"))
    assert c.overshoot[0, 0, 0] == 0.0
    assert c.rise_time[0, 0, 0] == pytest.approx(tau * np.log(9), abs=2 * DT)
    assert c.settling_time[0, 0, 0] == pytest.approx(tau * np.log(50), abs=2 * DT)
    assert c.steady_state_error[0, 0, 0] < 1e-8
    w = (1 - np.exp(-1)) * 0 + np.exp(-1) * (tau * np.log(50) - tau * np.log(9))
    assert c.score[0] == pytest.approx(w, abs=2 * DT)


def test_criteria_of_an_underdamped_response() -> None:
    zeta, wn = 0.3, 60.0
    t = np.arange(600) * DT
    wd = wn * np.sqrt(1 - zeta**2)
    phi = np.arccos(zeta)
    trace = np.exp(-zeta * wn * t) * np.sin(wd * t + phi) / np.sin(phi)
    c = _criteria(trace)
    assert c.overshoot[0, 0, 0] == pytest.approx(
        np.exp(-zeta * np.pi / np.sqrt(1 - zeta**2)), rel=0.02
    )


def test_error_that_never_settles_and_divergence() -> None:
    t = np.arange(400) * DT
    stuck = _criteria(np.full(t.size, 0.5))
    assert stuck.rise_time[0, 0, 0] == pytest.approx(0.4)  # never reaches 10 %: the horizon
    assert stuck.settling_time[0, 0, 0] == pytest.approx(0.4)
    assert stuck.steady_state_error[0, 0, 0] == pytest.approx(0.5)
    err = np.full((1, 1, 400, 1), np.nan)
    c = criteria_from_errors(err, np.array([[0.05]]), DT, ObjectiveSettings(), np.array([[10]]))
    assert c.diverged.all() and c.score[0] == np.inf


def test_absurd_gains_score_inf_without_crashing(compose: Callable[..., DictConfig]) -> None:
    obj = build_objective(compose("tuner.objective.n_scenarios=2", "tuner.objective.horizon=0.1"))
    scores = obj(np.array([[1e7, 1e7, 10.0, 1.0, 0.01], [668, 552, 1.8, 0.001, 0.69]]))
    assert scores[0] == np.inf and np.isfinite(scores[1])


def test_tuned_adaptive_gains_beat_the_papers(compose: Callable[..., DictConfig]) -> None:
    cfg = compose("tuner.objective.n_scenarios=4", "tuner.objective.horizon=0.3")
    obj = build_objective(cfg)
    space = search_space(cfg)
    lower, upper = space.search_lower, space.search_upper
    paper = obj(gain_vector(ADAPTIVE, PAPER_GAINS, 2)[None])[0]
    res = cuckoo_search(
        space.objective(obj), lower, upper, n_nests=10, n_iterations=30, seed=1, step_scale=0.3
    )
    assert res.best_f <= paper
    assert np.all((res.best_x >= lower) & (res.best_x <= upper))
    best = space.gains(res.best_x)[0]
    assert obj(best[None])[0] == res.best_f


def test_tuned_pid_is_stable_on_every_scenario(compose: Callable[..., DictConfig]) -> None:
    cfg = compose("controller=pid", "tuner.objective.n_scenarios=4", "tuner.objective.horizon=0.4")
    obj = build_objective(cfg)
    assert obj.kind == PID
    space = search_space(cfg)
    res = cuckoo_search(
        space.objective(obj), space.search_lower, space.search_upper, n_nests=10,
        n_iterations=30, seed=1, step_scale=0.3,
    )  # fmt: skip
    best = space.gains(res.best_x)
    crit = obj.criteria(best)
    assert not crit.diverged.any()
    trace, _ = obj.simulate(best)
    err = trace[..., :2]  # e1; the torque follows
    offset = obj.scenarios.offset
    # bounded error: never more than twice the initial offset, and well inside it at the end
    assert np.abs(err).max() <= 2 * np.abs(offset).max()
    assert np.abs(err[:, :, -100:, :]).max() < 0.2 * np.abs(offset).max()


def test_itae_and_iae_against_hand_computed_cases() -> None:
    """ε = 1 until 0.1 s, then 0.5 until 0.3 s, then 0 (a staircase): IAE = 0.1 + 0.1 = 0.2 s and
    ITAE = ∫₀^0.1 t dt + 0.5 ∫_0.1^0.3 t dt = 0.005 + 0.02 = 0.025 s², as Riemann sums on the
    1 ms grid (t = k dt, left points)."""
    k = np.arange(400)
    trace = np.where(k < 100, 1.0, np.where(k < 300, 0.5, 0.0))
    t = k * DT
    c = _criteria(trace, ObjectiveSettings(criterion="itae", effort_weight=0.0))
    assert c.iae[0, 0, 0] == pytest.approx(0.2, abs=1e-12)
    assert c.itae[0, 0, 0] == pytest.approx(float((t * trace).sum() * DT), rel=1e-12)
    assert c.itae[0, 0, 0] == pytest.approx(0.025, abs=0.5 * DT)  # the integral, to the grid
    assert c.score[0] == pytest.approx(c.itae[0, 0, 0])
    iae = _criteria(trace, ObjectiveSettings(criterion="iae"))
    assert iae.score[0] == pytest.approx(0.2)
    # A negative error (overshoot) counts by its magnitude.
    assert _criteria(-trace, ObjectiveSettings(criterion="itae")).score[0] == pytest.approx(
        c.score[0]
    )


def test_the_criterion_picks_the_score_and_the_horizon_defaults_follow_it() -> None:
    t = np.arange(600) * DT
    trace = np.exp(-t / 0.05)
    scores = {k: _criteria(trace, ObjectiveSettings(criterion=k)) for k in ("gaing", "itae")}
    assert scores["gaing"].score[0] == pytest.approx(scores["gaing"].criterion[0])
    assert scores["itae"].score[0] == pytest.approx(0.05**2, rel=0.05)  # ∫ t e^{-t/τ} = τ²
    assert resolved_horizon("gaing", None) == 0.6
    assert resolved_horizon("itae", None) == resolved_horizon("iae", None) == 1.5
    assert resolved_horizon("gaing", 2.0) == 2.0
    with pytest.raises(ValueError, match="criterion=foo"):
        resolved_horizon("foo", None)


def test_effort_penalty_scales_the_criterion() -> None:
    """score = J (1 + effort_weight P + saturation_weight L): a relative penalty."""
    trace = np.exp(-np.arange(600) * DT / 0.05)
    err = (0.05 * trace)[None, None, :, None]
    torque = np.full_like(err, 50.0)
    torque[..., 400:, :] = 100.0  # at the limit over the last 200 of the 300 tracked steps
    settings = ObjectiveSettings(criterion="itae", effort_weight=0.1, saturation_weight=1.0)
    c = criteria_from_errors(
        err, np.array([[0.05]]), DT, settings, np.array([[600]]), torque=torque,
        limit=np.array([100.0]),
    )  # fmt: skip
    assert c.peak_ratio[0] == pytest.approx(1.0)
    assert c.time_at_limit[0] == pytest.approx(200 / 300)
    assert c.score[0] == pytest.approx(c.criterion[0] * (1 + 0.1 + 200 / 300))


def test_search_space_maps_points_to_gains_and_back(compose: Callable[..., DictConfig]) -> None:
    """The adaptive law's search point (log10 of a0, a1, λ, γ) gives gains with r1 = 1 and the
    same λ = c1 r1, γ = b1² c1; the paper's gains map to a point inside the box."""
    space = search_space(compose())
    assert space.names == ("a0", "a1", "lambda", "gamma")
    paper = gain_vector(ADAPTIVE, PAPER_GAINS, 2)
    point = space.point(paper)
    assert np.all((point > space.search_lower) & (point < space.search_upper))
    back = space.gains(point)[0]
    assert back[4] == 1.0 and back[:2] == pytest.approx(paper[:2])
    assert back[3] * back[4] == pytest.approx(paper[3] * paper[4])  # λ
    assert back[2] ** 2 * back[3] == pytest.approx(paper[2] ** 2 * paper[3])  # γ
    assert space.on_bound(back) == []
    pid = search_space(compose("controller=pid"))
    low = pid.gains(pid.search_lower)[0]
    assert low == pytest.approx(pid.lower) and len(pid.on_bound(low)) == 6
    zero_ki = gain_vector(PID, {"kp": [1e5, 1e4], "ki": [0.0, 0.0], "kd": [100.0, 10.0]}, 2)
    assert pid.point(zero_ki)[2:4] == pytest.approx(np.log10(pid.lower[2:4]))  # clipped, no -inf
