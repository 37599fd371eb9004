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

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["ABANDON_RULES", "CuckooResult", "cuckoo_search", "n_abandoned"]

#: The abandonment rules of phase 2 (docs/design.md §5).
ABANDON_RULES = ("worst", "per_component")

FloatArray = NDArray[np.float64]
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


def _fail(message: str) -> NoReturn:
    raise ValueError(message)


def _as_bounds(name: str, value: ArrayLike) -> FloatArray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name}={value!r} is not a sequence of numbers; give one number per dimension."
        ) from None
    if arr.ndim != 1:
        _fail(
            f"{name} has shape {arr.shape}; it must be a 1-D sequence with one number "
            "per dimension."
        )
    if arr.size == 0:
        _fail(f"{name}={value!r} is empty; give at least one bound.")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        _fail(f"{name}[{i}]={float(arr[i])!r} is not finite; every bound must be a finite number.")
    return arr


def _as_real(name: str, value: object) -> float:
    if isinstance(value, bool):
        _fail(f"{name}={value!r} is not a number.")
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} is not a number.") from None


def _as_int(name: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        _fail(f"{name}={value!r} is not an integer; it must be an integer >= {minimum}.")
    result = int(value)
    if result < minimum:
        _fail(f"{name}={result} is too small; it must be an integer >= {minimum}.")
    return result


def _mantegna_sigma(beta: float) -> float:
    num = math.gamma(1.0 + beta) * math.sin(math.pi * beta / 2.0)
    den = math.gamma((1.0 + beta) / 2.0) * beta * 2.0 ** ((beta - 1.0) / 2.0)
    # At beta == 2 the sine is ~1e-16 (possibly of either sign in other libms); the Lévy step
    # then vanishes, which is the documented degenerate limit rather than an error.
    return float(max(num / den, 0.0) ** (1.0 / beta))


def n_abandoned(n_nests: int, pa: float) -> int:
    """Nests discarded per iteration by the ``"worst"`` rule: ``pa * n_nests`` rounded half up,
    capped at ``n_nests - 1`` so the best nest always survives."""
    return min(math.floor(pa * n_nests + 0.5), n_nests - 1)


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
    lo = _as_bounds("lower", lower)
    hi = _as_bounds("upper", upper)
    if lo.shape != hi.shape:
        _fail(
            f"lower has {lo.size} entries but upper has {hi.size}; they must have the same "
            "length, one per dimension."
        )
    not_below = np.flatnonzero(lo >= hi)
    if not_below.size:
        i = int(not_below[0])
        relation = "equal to" if lo[i] == hi[i] else "greater than"
        _fail(
            f"lower[{i}]={float(lo[i])!r} is {relation} upper[{i}]={float(hi[i])!r}; "
            "every lower bound must be strictly below its upper bound."
        )
    n = _as_int("n_nests", n_nests, 2)
    n_iter = _as_int("n_iterations", n_iterations, 0)
    pa_f = _as_real("pa", pa)
    if not 0.0 <= pa_f <= 1.0:
        _fail(f"pa={pa_f!r} is outside [0, 1]; it is a probability.")
    beta_f = _as_real("beta", beta)
    if not 0.0 < beta_f <= 2.0:
        _fail(f"beta={beta_f!r} is outside (0, 2]; the Lévy exponent must satisfy 0 < beta <= 2.")
    scale = _as_real("step_scale", step_scale)
    if not (scale > 0.0 and math.isfinite(scale)):
        _fail(f"step_scale={scale!r} is not allowed; it must be a finite number above 0.")
    if not isinstance(abandon, str) or abandon not in ABANDON_RULES:
        _fail(
            f"abandon={abandon!r} is not a known rule; it must be one of "
            f"{', '.join(ABANDON_RULES)}."
        )
    if callback is not None and not callable(callback):
        _fail(f"callback={callback!r} is not callable; give a function or None.")
    if not callable(objective):
        _fail(f"objective={objective!r} is not callable; give a function.")

    d = lo.size
    span = hi - lo
    sigma_u = _mantegna_sigma(beta_f)
    rng = np.random.default_rng(seed)

    n_worst = n_abandoned(n, pa_f) if abandon == "worst" else n
    total = n + n_iter * (n + n_worst)
    evaluations = np.empty((total, d), dtype=np.float64)
    scores = np.empty(total, dtype=np.float64)
    iterations = np.empty(total, dtype=np.int64)
    history = np.empty(n_iter, dtype=np.float64)
    n_done = 0

    def evaluate(candidates: FloatArray, iteration: int) -> FloatArray:
        """Score ``candidates``, record them, and return NaN-free ranking keys."""
        nonlocal n_done
        m = candidates.shape[0]
        if m == 0:
            return np.empty(0, dtype=np.float64)
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
                _fail(
                    f"objective returned {values.size} values for a batch of {m} candidates; "
                    f"it must return exactly {m} (one per row), or use batch=False."
                )
        else:
            values = np.empty(m, dtype=np.float64)
            for k in range(m):
                raw = objective(candidates[k].copy())
                try:
                    one = np.asarray(raw, dtype=np.float64).reshape(-1)
                except (TypeError, ValueError):
                    one = np.empty(0)
                if one.size != 1:
                    _fail(
                        f"objective returned {raw!r} for one candidate; with batch=False it "
                        "must return a single number."
                    )
                values[k] = one[0]
        stop = n_done + m
        evaluations[n_done:stop] = candidates
        scores[n_done:stop] = values
        iterations[n_done:stop] = iteration
        n_done = stop
        return np.where(np.isnan(values), np.inf, values)

    def snapshot(iteration: int, best: int) -> CuckooResult:
        views = (history[:iteration], evaluations[:n_done], scores[:n_done], iterations[:n_done])
        for view in views:
            view.flags.writeable = False
        return CuckooResult(
            best_x=nests[best].copy(),
            best_f=float(keys[best]),
            history=views[0],
            n_evaluations=n_done,
            evaluations=views[1],
            scores=views[2],
            iterations=views[3],
        )

    nests = lo + rng.random((n, d)) * span
    if start is not None:
        first = _as_bounds("start", start)
        if first.shape != lo.shape:
            _fail(f"start has {first.size} entries; it must have one per dimension ({d}).")
        nests[0] = np.clip(first, lo, hi)
    keys = evaluate(nests, 0)

    for it in range(1, n_iter + 1):
        # Lévy flights (eqs. 15-18). The draws are made as whole arrays up front so their
        # order, and hence the run, does not depend on the objective or on ``batch``.
        best = int(np.argmin(keys))
        u = rng.standard_normal((n, d)) * sigma_u
        v = rng.standard_normal((n, d))
        ell = rng.standard_normal((n, d))
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            stp = u / np.abs(v) ** (1.0 / beta_f)
            proposal = nests + ell * (scale * stp * (nests - nests[best]))
        # v can be ~0, giving an inf/NaN step; a NaN would survive np.clip, so fall back to
        # the unmoved nest for those components (inf is clipped to the bound as usual).
        proposal = np.where(np.isnan(proposal), nests, proposal)
        np.clip(proposal, lo, hi, out=proposal)
        new_keys = evaluate(proposal, it)
        better = new_keys < keys
        nests[better] = proposal[better]
        keys[better] = new_keys[better]

        # Abandonment (eq. 19): a differential step between two randomly paired nests. The
        # same draws are made under both rules, whatever the scores.
        discovered = rng.random((n, d)) < pa_f
        iota = rng.permutation(n)
        kappa = rng.permutation(n)
        r = rng.random((n, 1))
        walk = r * (nests[iota] - nests[kappa])
        if abandon == "per_component":
            # Only the discovered components move; greedy replacement.
            proposal = nests + walk * discovered
            np.clip(proposal, lo, hi, out=proposal)
            new_keys = evaluate(proposal, it)
            better = new_keys < keys
            nests[better] = proposal[better]
            keys[better] = new_keys[better]
        else:
            # The n_worst worst nests (ties: the later index is the worse) are discarded and
            # rebuilt by the walk on every component; the new nests replace them outright.
            worst = np.argsort(keys, kind="stable")[n - n_worst :]
            proposal = nests[worst] + walk[worst]
            np.clip(proposal, lo, hi, out=proposal)
            nests[worst] = proposal
            keys[worst] = evaluate(proposal, it)

        best = int(np.argmin(keys))
        history[it - 1] = keys[best]
        if callback is not None:
            callback(it, snapshot(it, best))

    best = int(np.argmin(keys))
    return CuckooResult(
        best_x=nests[best].copy(),
        best_f=float(keys[best]),
        history=history,
        n_evaluations=n_done,
        evaluations=evaluations,
        scores=scores,
        iterations=iterations,
    )
