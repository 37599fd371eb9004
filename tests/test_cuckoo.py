"""Tests of the cuckoo search optimiser (paper Algorithm 2, eqs. 15-19)."""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from armexp.tune.cuckoo import CuckooResult, cuckoo_search

FloatArray = NDArray[np.float64]

N_NESTS = 15
N_ITER = 200
BOX_LO = [-5.12] * 5
BOX_HI = [5.12] * 5


def sphere(x: FloatArray) -> FloatArray:
    return np.asarray(np.sum(x**2, axis=1))


def rastrigin(x: FloatArray) -> FloatArray:
    return np.asarray(10.0 * x.shape[1] + np.sum(x**2 - 10.0 * np.cos(2.0 * np.pi * x), axis=1))


class Recorder:
    """Batch objective wrapper that keeps every row it was asked to evaluate."""

    def __init__(self, f: Callable[[FloatArray], FloatArray]) -> None:
        self.f = f
        self.rows: list[FloatArray] = []
        self.calls = 0

    def __call__(self, x: FloatArray) -> FloatArray:
        self.calls += 1
        self.rows.append(np.array(x, copy=True))
        return self.f(x)


def assert_same(a: CuckooResult, b: CuckooResult) -> None:
    np.testing.assert_array_equal(a.best_x, b.best_x)
    assert a.best_f == b.best_f
    np.testing.assert_array_equal(a.history, b.history)
    np.testing.assert_array_equal(a.evaluations, b.evaluations)
    np.testing.assert_array_equal(a.scores, b.scores)
    np.testing.assert_array_equal(a.iterations, b.iterations)
    assert a.n_evaluations == b.n_evaluations


def test_sphere_median_with_paper_budget() -> None:
    best = [cuckoo_search(sphere, BOX_LO, BOX_HI, seed=s).best_f for s in range(10)]
    assert np.median(best) < 1e-4


def test_rastrigin_median_with_paper_budget() -> None:
    best = [cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=s).best_f for s in range(10)]
    assert np.median(best) < 10.0


def test_same_seed_is_bit_identical_and_different_seeds_differ() -> None:
    a = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=7, n_iterations=50)
    b = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=7, n_iterations=50)
    c = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=8, n_iterations=50)
    assert_same(a, b)
    assert not np.array_equal(a.evaluations, c.evaluations)
    assert not np.array_equal(a.best_x, c.best_x)
    assert not np.array_equal(a.history, c.history)


def test_batch_and_per_candidate_calls_give_identical_results() -> None:
    def one(x: FloatArray) -> float:
        assert x.shape == (5,)
        return float(rastrigin(x[None, :])[0])

    a = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=3, n_iterations=40, batch=True)
    b = cuckoo_search(one, BOX_LO, BOX_HI, seed=3, n_iterations=40, batch=False)
    assert_same(a, b)


@pytest.mark.parametrize(
    ("lower", "upper"),
    [(BOX_LO, BOX_HI), ([0.0, -1.0, 10.0], [1.0, 3.0, 20.0])],
)
def test_bounds_are_never_violated(lower: list[float], upper: list[float]) -> None:
    lo, hi = np.array(lower), np.array(upper)
    # The optimum lies far outside the box, which pushes many proposals against the bounds.
    target = np.where(np.arange(lo.size) % 2 == 0, hi + 100.0, lo - 100.0)
    rec = Recorder(lambda x: np.sum((x - target) ** 2, axis=1))
    res = cuckoo_search(rec, lower, upper, seed=1, n_iterations=100, beta=1.0)
    seen = np.concatenate(rec.rows)
    for pts in (seen, res.evaluations):
        assert np.all(pts >= lo) and np.all(pts <= hi)
    np.testing.assert_allclose(res.best_x, np.clip(target, lo, hi), atol=1e-6)


def test_history_and_evaluation_bookkeeping() -> None:
    rec = Recorder(sphere)
    res = cuckoo_search(rec, BOX_LO, BOX_HI, seed=0)
    assert res.history.shape == (N_ITER,)
    assert np.all(np.diff(res.history) <= 0.0)
    assert res.history[-1] == res.best_f
    expected = N_NESTS + 2 * N_NESTS * N_ITER
    assert res.n_evaluations == expected == len(res.evaluations) == len(res.scores)
    assert sum(len(r) for r in rec.rows) == expected
    assert rec.calls == 1 + 2 * N_ITER  # one batch call per phase
    np.testing.assert_array_equal(np.concatenate(rec.rows), res.evaluations)
    np.testing.assert_array_equal(res.scores, sphere(res.evaluations))
    assert res.best_f == res.scores.min()
    assert res.best_f == sphere(res.best_x[None, :])[0]
    expected_iters = np.repeat(np.r_[0, np.repeat(np.arange(1, N_ITER + 1), 2)], N_NESTS)
    np.testing.assert_array_equal(res.iterations, expected_iters)


def test_zero_iterations_returns_the_initial_population() -> None:
    res = cuckoo_search(sphere, BOX_LO, BOX_HI, n_iterations=0, n_nests=4)
    assert res.history.shape == (0,)
    assert res.n_evaluations == 4
    assert res.best_f == res.scores.min()


def test_nan_and_inf_regions_are_avoided() -> None:
    def partly_undefined(x: FloatArray) -> FloatArray:
        f: FloatArray = np.asarray(np.sum((x + 1.0) ** 2, axis=1), dtype=np.float64)
        f[x[:, 0] > 0.0] = np.nan
        f[x[:, 1] > 3.0] = np.inf
        return f

    res = cuckoo_search(partly_undefined, BOX_LO, BOX_HI, seed=0)
    assert np.isfinite(res.best_f)
    assert res.best_f < 1e-2
    np.testing.assert_allclose(res.best_x, -1.0, atol=0.05)
    assert np.all(np.isfinite(res.history))
    # Raw scores are kept as the objective returned them.
    assert np.isnan(res.scores).any() and np.isposinf(res.scores).any()


@pytest.mark.parametrize(
    ("kwargs", "words"),
    [
        ({"lower": [0.0, 5.0], "upper": [1.0, 1.0]}, ["lower[1]=5.0", "upper[1]=1.0"]),
        ({"lower": [0.0, 1.0], "upper": [1.0, 1.0]}, ["lower[1]=1.0", "upper[1]=1.0"]),
        ({"lower": [0.0, 0.0, 0.0], "upper": [1.0, 1.0]}, ["lower", "3", "upper", "2"]),
        ({"lower": [0.0, np.inf], "upper": [1.0, 1.0]}, ["lower[1]=inf"]),
        ({"lower": [], "upper": []}, ["lower"]),
        ({"lower": [[0.0]], "upper": [[1.0]]}, ["lower", "(1, 1)"]),
        ({"lower": ["a"], "upper": [1.0]}, ["lower", "'a'"]),
        ({"n_nests": 1}, ["n_nests=1"]),
        ({"n_nests": 2.5}, ["n_nests=2.5"]),
        ({"n_iterations": -1}, ["n_iterations=-1"]),
        ({"pa": 1.5}, ["pa=1.5"]),
        ({"pa": -0.1}, ["pa=-0.1"]),
        ({"beta": 0}, ["beta=0"]),
        ({"beta": 2.5}, ["beta=2.5"]),
        ({"step_scale": 0.0}, ["step_scale=0.0"]),
        ({"callback": 3}, ["callback=3"]),
    ],
)
def test_invalid_arguments_raise_value_error(kwargs: dict[str, object], words: list[str]) -> None:
    args: dict[str, object] = {"lower": [0.0, 0.0], "upper": [1.0, 1.0]}
    args.update(kwargs)
    lower, upper = args.pop("lower"), args.pop("upper")
    with pytest.raises(ValueError) as info:
        cuckoo_search(sphere, lower, upper, **args)  # type: ignore[arg-type]
    message = str(info.value)
    for word in words:
        assert word in message
    assert message.count("\n") == 0


def test_wrong_length_objective_output_is_a_value_error() -> None:
    with pytest.raises(ValueError, match=re.escape("returned 3 values for a batch of 15")):
        cuckoo_search(lambda x: np.zeros(3), BOX_LO, BOX_HI)
    with pytest.raises(ValueError, match="single number"):
        cuckoo_search(lambda x: np.zeros(2), BOX_LO, BOX_HI, batch=False)
    with pytest.raises(ValueError, match="batch of 15"):
        cuckoo_search(lambda x: None, BOX_LO, BOX_HI)


def test_callback_sees_every_iteration_in_order() -> None:
    seen: list[tuple[int, float, int, int]] = []

    def callback(iteration: int, partial: CuckooResult) -> None:
        assert isinstance(partial, CuckooResult)
        assert partial.history.shape == (iteration,)
        assert partial.history[-1] == partial.best_f
        assert not partial.evaluations.flags.writeable
        seen.append((iteration, partial.best_f, partial.n_evaluations, len(partial.evaluations)))

    res = cuckoo_search(sphere, BOX_LO, BOX_HI, n_iterations=30, callback=callback)
    assert [s[0] for s in seen] == list(range(1, 31))
    assert [s[2] for s in seen] == [N_NESTS * (1 + 2 * i) for i in range(1, 31)]
    assert all(s[2] == s[3] for s in seen)
    np.testing.assert_array_equal([s[1] for s in seen], res.history)
    # The final result is not affected by the read-only views given to the callback.
    assert res.evaluations.flags.writeable


# ------------------------------------------------------ abandonment rules (docs/design.md §5)
RULES = ("worst", "per_component")


@pytest.mark.parametrize("rule", RULES)
def test_each_rule_is_deterministic_for_a_seed_and_batch_independent(rule: str) -> None:
    def one(x: FloatArray) -> float:
        return float(rastrigin(x[None, :])[0])

    a = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=5, n_iterations=40, abandon=rule)
    b = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=5, n_iterations=40, abandon=rule)
    c = cuckoo_search(one, BOX_LO, BOX_HI, seed=5, n_iterations=40, abandon=rule, batch=False)
    d = cuckoo_search(rastrigin, BOX_LO, BOX_HI, seed=6, n_iterations=40, abandon=rule)
    assert_same(a, b)
    assert_same(a, c)
    assert not np.array_equal(a.evaluations, d.evaluations)
    assert np.all(np.diff(a.history) <= 0.0) and a.history[-1] == a.best_f


def test_the_rules_differ() -> None:
    a = cuckoo_search(sphere, BOX_LO, BOX_HI, seed=0, n_iterations=5, abandon="worst")
    b = cuckoo_search(sphere, BOX_LO, BOX_HI, seed=0, n_iterations=5, abandon="per_component")
    assert a.n_evaluations != b.n_evaluations
    assert not np.array_equal(a.best_x, b.best_x)


@pytest.mark.parametrize("rule", RULES)
def test_each_rule_minimises_a_sphere_within_a_small_budget(rule: str) -> None:
    for seed in range(5):
        box = ([-5.12] * 3, [5.12] * 3)
        res = cuckoo_search(sphere, *box, n_iterations=100, step_scale=0.3, seed=seed, abandon=rule)
        assert res.best_f < 1e-3, (seed, res.best_f)
        assert res.n_evaluations == len(res.evaluations)


@pytest.mark.parametrize(
    ("n_nests", "pa", "m"),
    [(15, 0.25, 4), (10, 0.5, 5), (8, 0.1, 1), (8, 0.05, 0), (5, 1.0, 4), (6, 0.75, 5)],
)
def test_worst_evaluates_round_pa_eta_new_nests_per_iteration(
    n_nests: int, pa: float, m: int
) -> None:
    rec = Recorder(sphere)
    n_iter = 7
    res = cuckoo_search(
        rec, BOX_LO, BOX_HI, n_nests=n_nests, pa=pa, n_iterations=n_iter, abandon="worst"
    )
    sizes = [len(r) for r in rec.rows]
    # Initial population, then per iteration the Lévy batch and (when m > 0) the m new nests.
    assert sizes == [n_nests] + ([n_nests, m] if m else [n_nests]) * n_iter
    assert res.n_evaluations == n_nests + n_iter * (n_nests + m) == len(res.scores)
    expected_iters = np.r_[np.zeros(n_nests), np.repeat(np.arange(1, n_iter + 1), n_nests + m)]
    np.testing.assert_array_equal(res.iterations, expected_iters)


def test_worst_discards_exactly_the_worst_nests_and_rebuilds_them_by_the_walk() -> None:
    """Replay the record: the Lévy batch is greedy; then the m worst nests (stable order) are
    replaced outright by x_w + r (x_a - x_b) for some nests a, b and some r in [0, 1]."""
    n, d, n_iter = 15, 4, 60
    m = round(0.25 * n)
    lo, hi = -50.0, 50.0  # wide box, optimum inside: clipping is rare; clipped rows are skipped
    rec = Recorder(lambda x: np.sum((x - 1.0) ** 2, axis=1))
    res = cuckoo_search(
        rec, [lo] * d, [hi] * d, n_nests=n, n_iterations=n_iter, step_scale=0.3, abandon="worst"
    )
    rows = iter(rec.rows)
    nests = next(rows).copy()
    keys = rec.f(nests)
    checked = 0
    for it in range(n_iter):
        levy = next(rows)
        f = rec.f(levy)
        better = f < keys
        nests[better], keys[better] = levy[better], f[better]
        new = next(rows)
        assert len(new) == m
        worst = np.argsort(keys, kind="stable")[n - m :]
        assert int(np.argmin(keys)) not in worst
        for k, w in enumerate(worst):
            if np.any(np.isin(new[k], [lo, hi])):
                continue
            step = new[k] - nests[w]
            diffs = nests[:, None, :] - nests[None, :, :]  # (a, b, d)
            nonzero = diffs != 0.0
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = step / diffs
            r_min = np.where(nonzero, ratio, np.inf).min(axis=2)
            r_max = np.where(nonzero, ratio, -np.inf).max(axis=2)
            ok = nonzero.any(axis=2) & np.all(nonzero | (step == 0.0), axis=2)
            ok &= (r_max - r_min < 1e-9) & (r_min >= -1e-12) & (r_max <= 1.0 + 1e-12)
            assert ok.any() or np.all(step == 0.0), (it, k)
            checked += 1
        nests[worst], keys[worst] = new, rec.f(new)  # unconditional replacement
        assert res.history[it] == keys.min()
    assert checked > n_iter * m // 2
    np.testing.assert_array_equal(res.best_x, nests[np.argmin(keys)])


@pytest.mark.parametrize("pa", [0.25, 0.6])
def test_per_component_rebuilds_components_with_probability_pa(pa: float) -> None:
    """With a flat objective no proposal is ever strictly better, so the nests stay the initial
    ones and every abandonment row differs from its nest exactly where the walk fired: with
    probability pa, times 1 - 1/n for the two permutations picking the same nest."""
    n, d, n_iter = 15, 10, 200
    rec = Recorder(lambda x: np.zeros(len(x)))
    res = cuckoo_search(
        rec, [0.0] * d, [1.0] * d, n_nests=n, pa=pa, n_iterations=n_iter, abandon="per_component"
    )
    nests = rec.rows[0]
    abandonment = np.stack(rec.rows[2::2])  # (n_iter, n, d)
    assert abandonment.shape == (n_iter, n, d)
    changed = abandonment != nests[None]
    expected = pa * (1.0 - 1.0 / n)
    assert abs(changed.mean() - expected) < 0.01, (changed.mean(), expected)
    # Every nest and every component is rebuilt at about the same rate.
    assert np.all(np.abs(changed.mean(axis=(0, 2)) - expected) < 0.05)
    assert np.all(np.abs(changed.mean(axis=(0, 1)) - expected) < 0.04)
    np.testing.assert_array_equal(res.best_x, nests[0])


def test_unknown_rule_is_a_one_sentence_value_error() -> None:
    with pytest.raises(ValueError, match=r"abandon='best'.*worst, per_component") as info:
        cuckoo_search(sphere, [0.0], [1.0], abandon="best")
    assert "\n" not in str(info.value)


def test_a_start_point_takes_the_first_nest_and_leaves_the_draws_alone() -> None:
    def sphere(x: np.ndarray) -> np.ndarray:
        return (x**2).sum(axis=1)

    lo, hi = [-5.0, -5.0], [5.0, 5.0]
    plain = cuckoo_search(sphere, lo, hi, n_nests=6, n_iterations=0, seed=3)
    started = cuckoo_search(sphere, lo, hi, n_nests=6, n_iterations=0, seed=3, start=[9.0, 0.5])
    assert np.array_equal(started.evaluations[0], [5.0, 0.5])  # clipped to the box
    assert np.array_equal(started.evaluations[1:], plain.evaluations[1:])
    with pytest.raises(ValueError, match="start has 3 entries"):
        cuckoo_search(sphere, lo, hi, n_nests=6, n_iterations=0, start=[0.0, 0.0, 0.0])
