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
