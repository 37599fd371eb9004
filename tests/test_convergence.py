"""Definition 1 (eqs. 9–10) measured on ‖e1‖ of a perturbed run: the fit against known decays,
ITAE and the settling time against hand-computed cases, and degenerate runs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armexp.sim.convergence import KEYS, definition_one, upper_envelope

DT = 1e-3
T = np.arange(0.0, 1.02, DT)  # a 34-action offset run: a little longer than the 1 s window


def _holds(t: np.ndarray, e: np.ndarray, m: dict[str, float], until: float) -> bool:
    """Eq. 9 with the measured constants, on the samples up to ``until`` s."""
    bound = m["decay_overshoot"] * np.exp(-m["decay_rate"] * t) * e[0] + m["ultimate_bound"]
    part = t <= until
    return bool(np.all(e[part] <= bound[part] * (1 + 1e-12)))


@pytest.mark.parametrize("seed", range(5))
def test_a_noisy_exponential_gives_its_rate_and_a_bound_near_its_floor(seed: int) -> None:
    amplitude, rate, floor, sigma = 0.05 * math.sqrt(2), 20.0, 1e-3, 1e-4
    noise = sigma * np.abs(np.random.default_rng(seed).standard_normal(T.size))
    e = amplitude * np.exp(-rate * T) + floor + noise
    m = definition_one(T, e, 0.05, 1.0, 1e-4)
    assert m["decay_rate"] == pytest.approx(rate, rel=0.04)
    # The true bound is the floor plus the noise's peak over the tail: a few sigma.
    assert floor < m["ultimate_bound"] <= floor + 5 * sigma
    assert m["ultimate_bound"] == pytest.approx(e[T >= 0.75][T[T >= 0.75] < 1.0].max())
    assert 1.0 <= m["decay_overshoot"] < 1.1
    assert _holds(T, e, m, until=0.15)
    assert m["settling_time"] == math.inf  # the floor (1 mrad) is at the band of 2 % of 50 mrad


def test_a_clean_exponential_is_fitted_exactly() -> None:
    amplitude, rate, floor = 0.007, 28.7, 1.35e-3
    e = amplitude * np.exp(-rate * T) + floor
    m = definition_one(T, e, 0.005, 1.0, 1e-4)
    assert m["decay_rate"] == pytest.approx(rate, rel=1e-3)
    assert m["ultimate_bound"] == pytest.approx(floor, rel=1e-3)
    # Eq. 9 with ‖e(t0)‖ = amplitude + floor: ᾱ = amplitude / (amplitude + floor).
    assert m["decay_overshoot"] == pytest.approx(amplitude / (amplitude + floor), rel=1e-3)
    assert _holds(T, e, m, until=0.2)


@pytest.mark.parametrize("omega", [30.0, 60.0])
def test_an_oscillating_decay_is_measured_by_its_peaks(omega: float) -> None:
    """‖e1‖ dips to the floor twice per period: the troughs are not convergence."""
    rate, floor = 20.0, 1e-3
    e = 0.07 * np.exp(-rate * T) * np.abs(np.cos(omega * T)) + floor
    m = definition_one(T, e, 0.05, 1.0, 1e-4)
    assert m["decay_rate"] == pytest.approx(rate, rel=0.05)
    assert m["ultimate_bound"] == pytest.approx(floor, rel=1e-3)
    assert _holds(T, e, m, until=0.2)
    # The peaks bound it: ᾱ e^{-αt} ‖e(t0)‖ meets them (no slack factor), the troughs are below.
    assert 0.9 < m["decay_overshoot"] <= 1.05


def test_an_error_that_first_grows_has_an_overshoot_above_one() -> None:
    rate = 30.0
    e = 0.014 * np.exp(-rate * T) + 1e-4
    e[0] = 0.007  # starts at half of what its decay implies: ᾱ ≈ 2
    m = definition_one(T, e, 0.005, 1.0, 1e-4)
    assert m["decay_rate"] == pytest.approx(rate, rel=1e-2)
    assert m["decay_overshoot"] == pytest.approx(0.014 / 0.007, rel=2e-2)
    assert _holds(T, e, m, until=0.3)


def test_itae_against_hand_computed_cases() -> None:
    # Constant 2 mrad for 0.5 s (the run ended before the 1 s window): ∫ t·c dt = c·T²/2.
    t = np.arange(0.0, 0.5 + DT / 2, DT)
    m = definition_one(t, np.full(t.size, 2e-3), 0.005, 1.0, 1e-4)
    assert m["itae"] == pytest.approx(2e-3 * 0.5**2 / 2, rel=1e-12)
    # ‖e1‖ = 1 − t, measured from t0 = 3 s, over a 0.4 s window of a longer run:
    # ∫_0^0.399 s (1 − s) ds (samples at whole milliseconds inside the window).
    s = np.arange(0.0, 1.0, DT)
    m = definition_one(3.0 + s, 1.0 - s, 0.05, 0.4, 1e-4)
    last = 0.399
    assert m["itae"] == pytest.approx(last**2 / 2 - last**3 / 3, rel=1e-5)


def test_settling_time_against_a_constructed_case() -> None:
    offset = 0.05  # band: 2 % of it, 1 mrad
    e = np.full(T.size, 0.5e-3)
    e[T < 0.3] = offset * math.sqrt(2)
    e[np.isclose(T, 0.5)] = 1.1e-3  # one sample outside the band at 0.5 s
    m = definition_one(T, e, offset, 1.0, 1e-4)
    assert m["settling_time"] == pytest.approx(0.501)
    e[np.isclose(T, 0.5)] = 0.99e-3  # inside: settled at 0.3 s
    assert definition_one(T, e, offset, 1.0, 1e-4)["settling_time"] == pytest.approx(0.3)
    # The tolerance is the band's floor: 2 % of 5 mrad is 0.1 mrad, below 0.5 mrad.
    assert definition_one(T, e, 0.005, 1.0, 1e-4)["settling_time"] == math.inf
    assert definition_one(T, e, 0.005, 1.0, 1e-3)["settling_time"] == pytest.approx(0.3)
    # Ends outside the band inside the window (what comes after the window does not count).
    late = e.copy()
    late[(T > 0.95) & (T < 0.9995)] = 2e-3
    late[T >= 1.0] = 0.0
    assert definition_one(T, late, offset, 1.0, 1e-4)["settling_time"] == math.inf


def test_degenerate_runs() -> None:
    empty = definition_one(np.zeros(0), np.zeros(0), 0.005, 1.0, 1e-4)
    assert set(empty) == set(KEYS) and all(math.isnan(v) for v in empty.values())
    # A run that starts inside its ultimate bound has no decay to measure.
    flat = definition_one(T, np.full(T.size, 3e-4), 0.005, 1.0, 1e-4)
    assert math.isnan(flat["decay_rate"]) and math.isnan(flat["decay_overshoot"])
    assert flat["ultimate_bound"] == pytest.approx(3e-4) and flat["settling_time"] == math.inf
    zero = definition_one(T, np.zeros(T.size), 0.005, 1.0, 1e-4)
    assert zero["settling_time"] == 0.0 and zero["itae"] == 0.0 and zero["ultimate_bound"] == 0
    assert math.isnan(zero["decay_rate"])
    one = definition_one(np.array([0.0]), np.array([0.007]), 0.005, 1.0, 1e-4)
    assert one["itae"] == 0.0 and math.isnan(one["decay_rate"]) and one["settling_time"] == math.inf
    # Two samples of a decay: too few for a rate.
    two = definition_one(T[:2], np.array([0.007, 1e-5]), 0.005, 1.0, 1e-4)
    assert math.isnan(two["decay_rate"]) and two["settling_time"] == pytest.approx(DT)
    # A diverged run never settles; nothing else is measurable.
    diverged = np.exp(T)
    diverged[500:] = np.inf
    m = definition_one(T, diverged, 0.005, 1.0, 1e-4)
    assert m["settling_time"] == math.inf
    assert all(math.isnan(m[k]) for k in KEYS if k != "settling_time")
    with pytest.raises(ValueError, match="one length"):
        definition_one(T, T[:-1], 0.005, 1.0, 1e-4)
    with pytest.raises(ValueError, match="window and offset must be > 0"):
        definition_one(T, T, 0.005, 0.0, 1e-4)


def test_the_envelope_is_non_increasing_and_above_the_error() -> None:
    e = np.array([1.0, 3.0, 2.0, 2.5, 0.5, 0.7, 0.1])
    env = upper_envelope(e)
    np.testing.assert_array_equal(env, [3.0, 3.0, 2.5, 2.5, 0.7, 0.7, 0.1])
    assert np.all(np.diff(env) <= 0) and np.all(env >= e)
