"""armexp.report.stats cross-checked against independent computations on fixed data."""

from __future__ import annotations

import math
import random

import numpy as np
import pytest
from scipy import stats as sps

from armexp.report.stats import (
    VERDICTS,
    iqm,
    performance_profile,
    performance_profile_ci,
    probability_of_improvement,
    probability_of_improvement_ci,
    relative_improvement_ci,
    stratified_bootstrap_ci,
    verdict,
)


def _data(shape: tuple[int, ...], seed: int = 1) -> np.ndarray:
    return np.random.default_rng(seed).normal(size=shape)


# -- IQM ---------------------------------------------------------------------------------------


def test_iqm_matches_hand_computation_and_trim_mean() -> None:
    x = _data((5, 4))  # 20 values, divisible by 4
    s = sorted(x.ravel().tolist())
    hand = sum(s[5:15]) / 10
    assert iqm(x) == pytest.approx(hand, rel=1e-12)
    assert iqm(x) == pytest.approx(sps.trim_mean(x.ravel(), 0.25), rel=1e-12)
    assert isinstance(iqm(x), float)
    per_column = iqm(x, axis=0)
    assert isinstance(per_column, np.ndarray)
    np.testing.assert_allclose(per_column, sps.trim_mean(x, 0.25, axis=0))


def test_iqm_ignores_outliers() -> None:
    x = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 1e9])
    assert iqm(x) == pytest.approx(4.5)


# -- stratified bootstrap ----------------------------------------------------------------------


def test_single_task_ci_matches_scipy_percentile_bootstrap() -> None:
    x = _data((30,), seed=2) * 2.0 + 1.0
    point, low, high = stratified_bootstrap_ci(x, np.mean, n_boot=10000, seed=0)
    ref = sps.bootstrap(
        (x,),
        np.mean,
        n_resamples=10000,
        confidence_level=0.95,
        method="percentile",
        random_state=np.random.default_rng(123),
    )
    width = ref.confidence_interval.high - ref.confidence_interval.low
    assert point == pytest.approx(float(np.mean(x)))
    assert abs(low - ref.confidence_interval.low) < 0.05 * width
    assert abs(high - ref.confidence_interval.high) < 0.05 * width


def _loop_bootstrap(scores: np.ndarray, n_boot: int, seed: int) -> list[float]:
    """Plain-Python stratified resampling (own RNG) of the IQM of a (runs, tasks) matrix."""
    rng = random.Random(seed)
    n_runs, n_tasks = scores.shape
    out = []
    for _ in range(n_boot):
        values = []
        for t in range(n_tasks):
            for _ in range(n_runs):
                values.append(float(scores[rng.randrange(n_runs), t]))
        values.sort()
        q = len(values) // 4
        out.append(sum(values[q : len(values) - q]) / (len(values) - 2 * q))
    return out


@pytest.mark.long
def test_multi_task_bootstrap_distribution_matches_loop_implementation() -> None:
    # Tasks on very different scales, so pooled (unstratified) resampling would differ.
    scores = _data((8, 3), seed=3) * np.array([1.0, 3.0, 0.5]) + np.array([0.0, 10.0, -4.0])
    n_boot = 4000
    ref = np.array(_loop_bootstrap(scores, n_boot, seed=7))
    seen: list[float] = []  # every statistic value: the point first, then the replicates

    def recording_iqm(s: np.ndarray) -> float:
        seen.append(float(iqm(s)))
        return seen[-1]

    point, low, high = stratified_bootstrap_ci(scores, recording_iqm, n_boot=n_boot, seed=11)
    reps = np.array(seen[1:])
    assert point == pytest.approx(sps.trim_mean(scores.ravel(), 0.25))
    assert reps.shape == (n_boot,)
    assert np.mean(reps) == pytest.approx(np.mean(ref), abs=0.05 * np.std(ref))
    assert np.std(reps) == pytest.approx(np.std(ref), rel=0.05)
    ref_low, ref_high = np.percentile(ref, [2.5, 97.5])
    width = ref_high - ref_low
    assert abs(low - ref_low) < 0.1 * width
    assert abs(high - ref_high) < 0.1 * width
    # An unstratified (pooled) resampling has a visibly different spread here.
    pooled = scores.ravel()
    rng = np.random.default_rng(0)
    unstrat = [float(iqm(rng.choice(pooled, size=pooled.size))) for _ in range(2000)]
    assert abs(np.std(unstrat) - np.std(ref)) > 0.2 * np.std(ref)


def test_bootstrap_resamples_within_each_task_column() -> None:
    # Disjoint value sets per column: every resampled column must only hold its own values.
    scores = np.arange(12, dtype=float).reshape(4, 3) * 10 + np.array([0.0, 1.0, 2.0])

    def column_check(s: np.ndarray) -> float:
        ok = all(np.isin(s[:, t], scores[:, t]).all() for t in range(3))
        return 1.0 if ok else 0.0

    _, low, high = stratified_bootstrap_ci(scores, column_check, n_boot=200)
    assert low == high == 1.0


def test_bootstrap_is_deterministic_for_a_seed() -> None:
    scores = _data((10, 4), seed=4)
    a = stratified_bootstrap_ci(scores, iqm, n_boot=500, seed=5)
    b = stratified_bootstrap_ci(scores, iqm, n_boot=500, seed=5)
    c = stratified_bootstrap_ci(scores, iqm, n_boot=500, seed=6)
    assert a == b
    assert a[1:] != c[1:]
    assert a[1] <= a[0] <= a[2]


# -- probability of improvement ----------------------------------------------------------------


def _brute_poi(x: np.ndarray, y: np.ndarray) -> float:
    per_task = []
    for t in range(x.shape[1]):
        count = 0.0
        for xi in x[:, t]:
            for yj in y[:, t]:
                count += 1.0 if xi > yj else 0.5 if xi == yj else 0.0
        per_task.append(count / (x.shape[0] * y.shape[0]))
    return sum(per_task) / len(per_task)


def test_probability_of_improvement_matches_mannwhitneyu_and_brute_force() -> None:
    rng = np.random.default_rng(8)
    x = np.round(rng.normal(0.3, 1.0, size=(7, 4)), 1)  # rounded: ties occur
    y = np.round(rng.normal(0.0, 1.0, size=(9, 4)), 1)
    mwu = np.mean([sps.mannwhitneyu(x[:, t], y[:, t]).statistic / (7 * 9) for t in range(4)])
    p = probability_of_improvement(x, y)
    assert p == pytest.approx(mwu, abs=1e-12)
    assert p == pytest.approx(_brute_poi(x, y), abs=1e-12)
    assert p + probability_of_improvement(y, x) == pytest.approx(1.0)
    # Lower is better: P(X < Y) = P(Y > X).
    assert probability_of_improvement(x, y, higher_is_better=False) == pytest.approx(
        probability_of_improvement(y, x)
    )


def test_probability_of_improvement_extremes_and_ci() -> None:
    x = np.full((5, 2), 2.0)
    y = np.full((6, 2), 1.0)
    assert probability_of_improvement(x, y) == 1.0
    assert probability_of_improvement(x, x) == 0.5
    rng = np.random.default_rng(9)
    a, b = rng.normal(1.0, 1.0, (10, 3)), rng.normal(0.0, 1.0, (10, 3))
    p, lo, hi = probability_of_improvement_ci(a, b, n_boot=500)
    assert p == pytest.approx(probability_of_improvement(a, b))
    assert 0.0 <= lo <= p <= hi <= 1.0
    with pytest.raises(ValueError):
        probability_of_improvement(a, b[:, :2])


# -- performance profile -----------------------------------------------------------------------


def test_performance_profile_matches_brute_force() -> None:
    scores = np.round(_data((6, 3), seed=10), 1)
    taus = np.linspace(-2.0, 2.0, 21)
    flat = scores.ravel().tolist()
    brute = [sum(1 for s in flat if s > tau) / len(flat) for tau in taus]
    np.testing.assert_allclose(performance_profile(scores, taus), brute)
    brute_low = [sum(1 for s in flat if s < tau) / len(flat) for tau in taus]
    np.testing.assert_allclose(performance_profile(scores, taus, higher_is_better=False), brute_low)
    prof, lo, hi = performance_profile_ci(scores, taus, n_boot=300)
    assert prof.shape == lo.shape == hi.shape == taus.shape
    assert np.all(lo <= prof + 1e-12) and np.all(prof <= hi + 1e-12)


# -- claim check -------------------------------------------------------------------------------


def test_relative_improvement_ci_recovers_20_percent() -> None:
    rng = np.random.default_rng(12)
    baseline = rng.normal(10.0, 0.5, size=(10, 5))
    proposed = rng.normal(8.0, 0.4, size=(10, 5))  # 20 % lower error
    point, low, high = relative_improvement_ci(proposed, baseline, n_boot=1000)
    assert point == pytest.approx(0.2, abs=0.02)
    assert low < 0.2 < high
    assert high - low < 0.05
    assert verdict(low, high, 0.18) == "consistent"
    assert verdict(low, high, 0.10) == "larger than claimed"
    # Higher is better: the same numbers as a score are a 20 % deterioration.
    up, _, _ = relative_improvement_ci(proposed, baseline, higher_is_better=True, n_boot=100)
    assert up == pytest.approx(-0.2, abs=0.02)


def test_relative_improvement_against_zero_baseline_is_nan() -> None:
    point, low, high = relative_improvement_ci(np.ones((4, 2)), np.zeros((4, 2)), n_boot=50)
    assert math.isnan(point) and math.isnan(low) and math.isnan(high)


@pytest.mark.parametrize(
    ("low", "high", "expected"),
    [
        # consistent: above 0 and covering the claimed 10 %, bounds included
        (0.05, 0.30, "consistent"),
        (0.10, 0.30, "consistent"),
        (0.01, 0.10, "consistent"),
        (0.10, 0.10, "consistent"),
        # larger than claimed: entirely above 10 %
        (0.20, 0.30, "larger than claimed"),
        (0.1000001, 0.9, "larger than claimed"),
        # smaller than claimed: between 0 and 10 %, exclusive of 0
        (0.01, 0.05, "smaller than claimed"),
        (1e-9, 0.0999999, "smaller than claimed"),
        # refuted: entirely below 0
        (-0.30, -0.01, "refuted"),
        (-0.30, -1e-12, "refuted"),
        # inconclusive: contains 0 (a bound on 0 counts) or a nan bound
        (-0.05, 0.30, "inconclusive"),
        (0.0, 0.30, "inconclusive"),
        (-0.30, 0.0, "inconclusive"),
        (0.0, 0.0, "inconclusive"),
        (math.nan, math.nan, "inconclusive"),
        (math.nan, 0.3, "inconclusive"),
        (0.2, math.nan, "inconclusive"),
    ],
)
def test_verdict(low: float, high: float, expected: str) -> None:
    assert verdict(low, high, 0.10) == expected
    assert expected in VERDICTS


def test_verdict_against_a_claim_of_zero_is_larger_whenever_it_is_above_zero() -> None:
    assert verdict(0.01, 0.02, 0.0) == "larger than claimed"
    assert verdict(0.0, 0.02, 0.0) == "inconclusive"
    assert verdict(-0.02, -0.01, 0.0) == "refuted"


def test_each_verdict_word_on_synthetic_seeds() -> None:
    """Error matrices (runs × tasks) with a known relative improvement: 2 %, 10 %, 40 %, −20 %
    and 0 % against a claimed 10 % give the five words."""
    rng = np.random.default_rng(3)
    baseline = rng.normal(10.0, 0.2, size=(12, 4))
    got = {}
    for size in (0.02, 0.10, 0.40, -0.20, 0.0):
        noise = 0.02 if size != 0.10 else 0.1  # a wider CI around the claim
        proposed = baseline * (1 - size) * (1 + noise * rng.standard_normal(baseline.shape))
        _, low, high = relative_improvement_ci(proposed, baseline, n_boot=500)
        got[size] = verdict(low, high, 0.10)
    assert got == {
        0.02: "smaller than claimed",
        0.10: "consistent",
        0.40: "larger than claimed",
        -0.20: "refuted",
        0.0: "inconclusive",
    }


def test_verdict_rejects_bad_input() -> None:
    with pytest.raises(ValueError):
        verdict(0.1, 0.2, -0.1)
    with pytest.raises(ValueError):
        verdict(0.1, 0.2, math.nan)
    with pytest.raises(ValueError):
        verdict(0.3, 0.2, 0.1)


def test_vectorised_replicates_equal_the_per_replicate_loop() -> None:
    """The IQM and relative-improvement statistics are computed for all replicates at once; the
    same draws through the generic loop (a wrapper the fast path does not know) agree."""
    rng = np.random.default_rng(3)
    a, b = rng.lognormal(size=(5, 4)), rng.lognormal(size=(5, 4)) + 0.5
    fast = stratified_bootstrap_ci(a, iqm, n_boot=300, seed=7)
    slow = stratified_bootstrap_ci(a, lambda s: iqm(s), n_boot=300, seed=7)
    assert fast == pytest.approx(slow, rel=1e-12)
    from armexp.report.stats import _bootstrap, _relative, iqm_columns_ci

    loop = _bootstrap([a, b], lambda p, q: _relative(p, q, False), 300, 0.95, 7)
    assert relative_improvement_ci(a, b, n_boot=300, seed=7) == pytest.approx(loop, rel=1e-12)
    cols = iqm_columns_ci(a, n_boot=300, seed=7)
    by_loop = stratified_bootstrap_ci(a, lambda s: iqm(s, axis=0), n_boot=300, seed=7)
    for x, y in zip(cols, by_loop, strict=True):
        assert np.allclose(x, y, rtol=1e-12)
