"""Cuckoo search optimisation (CSO), as used by the paper to tune the controller gains.

This is Yang & Deb's cuckoo search in the form given by the paper's section "Cuckoo Search
Optimization" (eqs. 15-19, Algorithm 2). A population of ``n_nests`` nests ``B_j`` (candidate
gain vectors, eta in the paper) lives inside the box ``[lower, upper]``. After the initial
population is drawn uniformly and evaluated (iteration 0), every iteration does two phases,
each of which proposes one candidate per nest, evaluates all of them in a single call of the
objective and keeps a proposal only where it is strictly better than the nest it came from:

1. Lévy flights (eqs. 15-18). With ``B_best`` the best nest at the start of the iteration,

   ``B_j(new) = B_j + l * step_scale * stp * (B_j - B_best)``

   elementwise, where ``l ~ N(0, 1)`` and ``stp = u / |v|**(1/beta)`` is Mantegna's symmetric
   Lévy-stable step with ``u ~ N(0, sigma_u**2)``, ``v ~ N(0, 1)`` and
   ``sigma_u = (G(1+beta) sin(pi beta / 2) / (G((1+beta)/2) beta 2**((beta-1)/2)))**(1/beta)``
   (``G`` is the gamma function). The paper's ``0.01`` factor of eq. 16 is ``step_scale``.

2. Abandonment (eq. 19, Algorithm 2 lines 9-12), by one of two rules (``abandon``):

   * ``"per_component"`` (Yang's reference implementation): each component of each nest is
     discovered by the host with probability ``pa`` and rebuilt by a biased random walk,

     ``B_j(new) = B_j + r_j * (B_iota - B_kappa)``   (only on the discovered components),

     where ``r_j ~ U(0, 1)`` is one number per nest and ``iota``, ``kappa`` come from two
     independent random permutations of the nests. All ``n_nests`` proposals are evaluated
     and kept only where strictly better (greedy), as in phase 1. (Yang's published MATLAB
     code, and NiaPy after it, tests ``rand > pa``, i.e. rebuilds a component with
     probability ``1 - pa``, with one ``r`` for all nests; the rate here is ``pa``, as the
     text of the paper and docs/design.md §5 have it.)
   * ``"worst"`` (Algorithm 2 line 9, "discard P_a of the worst nests"): the
     ``m = floor(pa * n_nests + 1/2)`` worst nests (at most ``n_nests - 1``: the best nest is
     never abandoned) are discarded and replaced, unconditionally, by new nests built with the
     same random walk applied to every component of the discarded nest. Only those ``m`` new
     nests are evaluated.

Proposals are clipped to the bounds before evaluation, so the objective never sees a point
outside ``[lower, upper]``. One run therefore costs ``n_nests * (1 + 2 * n_iterations)``
evaluations with ``"per_component"`` and ``n_nests + n_iterations * (n_nests + m)`` with
``"worst"``. NaN scores are ranked as ``+inf`` (never preferred to a finite score) but are
recorded as returned. All random numbers are drawn in the same order whatever the objective
returns and whether it is called in batches or per candidate, so a seed fixes the run.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from armexp.tune.cuckoo_settings import (
    ABANDON_RULES,
    FloatArray,
    Settings,
    as_bounds,
    check_arguments,
    fail,
    n_abandoned,
)

__all__ = ["ABANDON_RULES", "CuckooResult", "cuckoo_search", "n_abandoned"]

IntArray = NDArray[np.int64]


@dataclass(frozen=True, eq=False)
class CuckooResult:
    """Outcome of :func:`cuckoo_search` (also passed, partially filled, to its callback).

    Attributes:
        best_x: The best candidate found, shape ``(d,)``.
        best_f: Its objective value; ``inf`` if no finite value was ever seen (NaN counts as
            ``inf`` when ranking, so it is never reported as best).
        history: Best value after each iteration ``1..n_iterations``, shape
            ``(n_iterations,)``; non-increasing. Empty when ``n_iterations == 0``.
        n_evaluations: Number of candidates evaluated, ``n_nests * (1 + 2 * n_iterations)``
            for a complete run with ``abandon="per_component"``, ``n_nests + n_iterations *
            (n_nests + n_abandoned(n_nests, pa))`` with ``abandon="worst"``.
        evaluations: Every evaluated candidate in evaluation order, shape
            ``(n_evaluations, d)``; all lie within the bounds.
        scores: The objective value of each candidate as returned (``inf``/NaN kept), shape
            ``(n_evaluations,)``.
        iterations: Iteration at which each candidate was evaluated (0 for the initial
            population), shape ``(n_evaluations,)``.
    """

    best_x: FloatArray
    best_f: float
    history: FloatArray
    n_evaluations: int
    evaluations: FloatArray
    scores: FloatArray
    iterations: IntArray


Objective = Callable[[FloatArray], Any]
Callback = Callable[[int, CuckooResult], None]


def cuckoo_search(
    objective: Objective,
    lower: ArrayLike,
    upper: ArrayLike,
    *,
    n_nests: int = 15,
    n_iterations: int = 200,
    pa: float = 0.25,
    beta: float = 1.5,
    seed: int | None = 0,
    batch: bool = True,
    step_scale: float = 0.01,
    abandon: str = "per_component",
    callback: Callback | None = None,
    start: ArrayLike | None = None,
) -> CuckooResult:
    """Minimise ``objective`` over the box ``[lower, upper]`` by cuckoo search (Algorithm 2).

    Args:
        objective: With ``batch=True``, called with a ``(k, d)`` float64 array of candidates
            and must return ``k`` values (any array-like). With ``batch=False``, called once
            per candidate with a ``(d,)`` array and must return one number. Lower is better;
            ``inf`` and NaN are allowed (NaN ranks as ``inf``). It receives copies, so it may
            modify its argument.
        lower: Lower bounds, one finite number per dimension.
        upper: Upper bounds, same length as ``lower``, each strictly above its lower bound.
        n_nests: Population size (eta), at least 2 because eq. 19 mixes two nests.
        n_iterations: Number of iterations after the initial population, at least 0.
        pa: Discovery probability, in ``[0, 1]``: the probability that a nest component is
            rebuilt (``abandon="per_component"``) or the share of the nests, the worst ones,
            that is discarded each iteration (``abandon="worst"``).
        beta: Lévy exponent of Mantegna's step, in ``(0, 2]``.
        seed: Seed of ``numpy.random.default_rng``; ``None`` draws fresh entropy.
        batch: Whether ``objective`` takes a batch of candidates or a single one. It does not
            change the result.
        step_scale: Scale of the Lévy step, positive: 0.01 in eq. 16; the ``cso_paper`` tuner
            uses a larger one (docs/cso_quality.md).
        abandon: The abandonment rule of phase 2, ``"per_component"`` or ``"worst"`` (see the
            module docstring).
        callback: Called as ``callback(iteration, result_so_far)`` after each iteration
            ``1..n_iterations``; the partial result's arrays are read-only views.
        start: A known point (clipped to the box) that takes the place of the first nest of
            the initial population, e.g. a controller's configured gains; the random draws are
            the same with or without it.

    Returns:
        A :class:`CuckooResult` with the best point, its value, the convergence history and
        a record of every evaluation.

    Raises:
        ValueError: For an invalid argument, or an objective that returns the wrong number
            of values or something that is not a number; the message is one sentence naming
            the offending argument and value.
    """
    s = check_arguments(lower, upper, n_nests, n_iterations, pa, beta, step_scale, abandon)
    if callback is not None and not callable(callback):
        fail(f"callback={callback!r} is not callable; give a function or None.")
    if not callable(objective):
        fail(f"objective={objective!r} is not callable; give a function.")
    rng = np.random.default_rng(seed)
    record = _Record(objective, batch, s)
    nests = _initial_nests(rng, s, start)
    keys = record.evaluate(nests, 0)
    for it in range(1, s.n_iter + 1):
        _levy_flights(rng, nests, keys, s, record, it)
        _abandonment(rng, nests, keys, s, record, it)
        best = int(np.argmin(keys))
        record.history[it - 1] = keys[best]
        if callback is not None:
            callback(it, record.snapshot(it, nests, keys, best))
    return record.result(nests, keys)


def _score(objective: Objective, candidates: FloatArray, batch: bool) -> FloatArray:
    """The objective's values of ``candidates`` (one call, or one per candidate), as returned."""
    m = candidates.shape[0]
    if batch:
        raw = objective(candidates.copy())
        try:
            values = np.asarray(raw, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            raise ValueError(
                f"objective returned {raw!r} for a batch of {m} candidates; it must return "
                f"{m} numbers."
            ) from None
        if values.size != m:
            fail(
                f"objective returned {values.size} values for a batch of {m} candidates; "
                f"it must return exactly {m} (one per row), or use batch=False."
            )
        return values
    values = np.empty(m, dtype=np.float64)
    for k in range(m):
        raw = objective(candidates[k].copy())
        try:
            one = np.asarray(raw, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError):
            one = np.empty(0)
        if one.size != 1:
            fail(
                f"objective returned {raw!r} for one candidate; with batch=False it "
                "must return a single number."
            )
        values[k] = one[0]
    return values


class _Record:
    """Every candidate one run evaluates, in order, with its score and iteration, and the best
    value after each iteration."""

    def __init__(self, objective: Objective, batch: bool, s: Settings) -> None:
        self.objective, self.batch = objective, batch
        total = s.n + s.n_iter * (s.n + s.n_worst)
        self.evaluations = np.empty((total, s.d), dtype=np.float64)
        self.scores = np.empty(total, dtype=np.float64)
        self.iterations = np.empty(total, dtype=np.int64)
        self.history = np.empty(s.n_iter, dtype=np.float64)
        self.n_done = 0

    def evaluate(self, candidates: FloatArray, iteration: int) -> FloatArray:
        """Score ``candidates``, record them, and return NaN-free ranking keys."""
        m = candidates.shape[0]
        if m == 0:
            return np.empty(0, dtype=np.float64)
        values = _score(self.objective, candidates, self.batch)
        stop = self.n_done + m
        self.evaluations[self.n_done : stop] = candidates
        self.scores[self.n_done : stop] = values
        self.iterations[self.n_done : stop] = iteration
        self.n_done = stop
        return np.where(np.isnan(values), np.inf, values)

    def snapshot(
        self, iteration: int, nests: FloatArray, keys: FloatArray, best: int
    ) -> CuckooResult:
        """The result so far, its arrays read-only views (for the callback)."""
        n = self.n_done
        views = (self.history[:iteration], self.evaluations[:n], self.scores[:n],
                 self.iterations[:n])  # fmt: skip
        for view in views:
            view.flags.writeable = False
        return CuckooResult(
            best_x=nests[best].copy(),
            best_f=float(keys[best]),
            history=views[0],
            n_evaluations=n,
            evaluations=views[1],
            scores=views[2],
            iterations=views[3],
        )

    def result(self, nests: FloatArray, keys: FloatArray) -> CuckooResult:
        best = int(np.argmin(keys))
        return CuckooResult(
            best_x=nests[best].copy(),
            best_f=float(keys[best]),
            history=self.history,
            n_evaluations=self.n_done,
            evaluations=self.evaluations,
            scores=self.scores,
            iterations=self.iterations,
        )


def _initial_nests(rng: np.random.Generator, s: Settings, start: ArrayLike | None) -> FloatArray:
    """The initial population, drawn uniformly in the box; ``start`` (clipped) as the first."""
    nests = s.lo + rng.random((s.n, s.d)) * (s.hi - s.lo)
    if start is not None:
        first = as_bounds("start", start)
        if first.shape != s.lo.shape:
            fail(f"start has {first.size} entries; it must have one per dimension ({s.d}).")
        nests[0] = np.clip(first, s.lo, s.hi)
    return nests


def _keep_better(
    nests: FloatArray, keys: FloatArray, proposal: FloatArray, new_keys: FloatArray
) -> None:
    """Greedy replacement: a proposal takes its nest's place where strictly better."""
    better = new_keys < keys
    nests[better] = proposal[better]
    keys[better] = new_keys[better]


def _levy_flights(
    rng: np.random.Generator,
    nests: FloatArray,
    keys: FloatArray,
    s: Settings,
    record: _Record,
    it: int,
) -> None:
    """Phase 1 (eqs. 15-18): one Lévy flight per nest, relative to the best nest."""
    # The draws are made as whole arrays up front so their order, and hence the run, does not
    # depend on the objective or on ``batch``.
    best = int(np.argmin(keys))
    u = rng.standard_normal((s.n, s.d)) * s.sigma_u
    v = rng.standard_normal((s.n, s.d))
    ell = rng.standard_normal((s.n, s.d))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        stp = u / np.abs(v) ** (1.0 / s.beta)
        proposal = nests + ell * (s.scale * stp * (nests - nests[best]))
    # v can be ~0, giving an inf/NaN step; a NaN would survive np.clip, so fall back to
    # the unmoved nest for those components (inf is clipped to the bound as usual).
    proposal = np.where(np.isnan(proposal), nests, proposal)
    np.clip(proposal, s.lo, s.hi, out=proposal)
    _keep_better(nests, keys, proposal, record.evaluate(proposal, it))


def _abandonment(
    rng: np.random.Generator,
    nests: FloatArray,
    keys: FloatArray,
    s: Settings,
    record: _Record,
    it: int,
) -> None:
    """Phase 2 (eq. 19): a differential step between two randomly paired nests, by the rule
    ``s.abandon``. The same draws are made under both rules, whatever the scores."""
    discovered = rng.random((s.n, s.d)) < s.pa
    iota = rng.permutation(s.n)
    kappa = rng.permutation(s.n)
    r = rng.random((s.n, 1))
    walk = r * (nests[iota] - nests[kappa])
    if s.abandon == "per_component":
        # Only the discovered components move; greedy replacement.
        proposal = nests + walk * discovered
        np.clip(proposal, s.lo, s.hi, out=proposal)
        _keep_better(nests, keys, proposal, record.evaluate(proposal, it))
    else:
        # The n_worst worst nests (ties: the later index is the worse) are discarded and
        # rebuilt by the walk on every component; the new nests replace them outright.
        worst = np.argsort(keys, kind="stable")[s.n - s.n_worst :]
        proposal = nests[worst] + walk[worst]
        np.clip(proposal, s.lo, s.hi, out=proposal)
        nests[worst] = proposal
        keys[worst] = record.evaluate(proposal, it)
