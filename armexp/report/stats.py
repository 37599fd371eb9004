"""Robust statistics across seeds, after Agarwal et al., NeurIPS 2021.

R. Agarwal, M. Schwarzer, P. S. Castro, A. Courville, M. G. Bellemare, "Deep Reinforcement
Learning at the Edge of the Statistical Precipice", NeurIPS 2021 (the `rliable` library). This is
a small numpy/scipy re-implementation (docs/design.md §9; `rliable` is archived and pins old
dependencies):

* :func:`iqm`: interquartile mean (mean of the middle 50 % of the pooled scores),
* :func:`stratified_bootstrap_ci`: percentile confidence interval of any statistic of a
  ``(n_runs, n_tasks)`` score matrix, resampling runs with replacement within each task,
* :func:`probability_of_improvement` (+ ``_ci``): P(X > Y) from the Mann–Whitney U statistic,
  averaged over tasks,
* :func:`performance_profile` (+ ``_ci``): fraction of runs scoring above each threshold,
* :func:`relative_improvement_ci` and :func:`verdict`: the two-sided claim check of
  docs/design.md §9.

Score matrices have one row per run (seed, or seed × episode) and one column per task; a 1-D
array is read as a single task column.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np
import numpy.typing as npt
from scipy import stats as sps

Array = npt.NDArray[np.float64]
Scalar = float | Array
Seed = int | np.random.Generator | None


def _matrix(scores: npt.ArrayLike) -> Array:
    """`scores` as a float ``(n_runs, n_tasks)`` matrix (a 1-D array is one task column)."""
    a = np.asarray(scores, dtype=np.float64)
    if a.ndim == 1:
        a = a[:, None]
    if a.ndim != 2 or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"expected a non-empty (n_runs, n_tasks) array, got shape {a.shape}")
    return a


def _scalar(value: Array | float) -> Scalar:
    """A 0-d result as a Python float, anything else as an array."""
    a = np.asarray(value, dtype=np.float64)
    return float(a) if a.ndim == 0 else a


def iqm(x: npt.ArrayLike, axis: int | None = None) -> Scalar:
    """Interquartile mean: the mean of the scores left after dropping the lowest and the highest
    25 % (``scipy.stats.trim_mean(x, 0.25)``), over all values when ``axis`` is None.

    Agarwal et al. (2021, §4) recommend it as a point estimate that is robust to outlier runs yet
    more statistically efficient than the median.
    """
    a = np.asarray(x, dtype=np.float64)
    if axis is None:
        a = a.ravel()
        axis = 0
    return _scalar(sps.trim_mean(a, 0.25, axis=axis))


def _bootstrap(
    samples: Sequence[Array],
    statistic: Callable[..., Scalar],
    n_boot: int,
    confidence: float,
    seed: Seed,
) -> tuple[Scalar, Scalar, Scalar]:
    """Stratified percentile bootstrap of ``statistic(*samples)``.

    Each sample matrix is resampled independently; within a sample each task column draws its
    runs with replacement from that column only (rliable's ``StratifiedBootstrap``). The interval
    is the percentile interval of the replicates (``np.percentile``, linear interpolation). A
    non-finite point estimate or any non-finite replicate gives nan bounds (a ratio against zero
    has no interval).
    """
    if n_boot < 1:
        raise ValueError("n_boot must be >= 1")
    if not 0.0 < confidence < 1.0:
        raise ValueError("confidence must be in (0, 1)")
    rng = np.random.default_rng(seed)
    point = np.asarray(statistic(*samples), dtype=np.float64)
    # Vectorised index draws: (n_boot, n_runs, n_tasks) per sample, column j indexes column j.
    resampled = []
    for s in samples:
        n_runs, n_tasks = s.shape
        idx = rng.integers(0, n_runs, size=(n_boot, n_runs, n_tasks))
        resampled.append(s[idx, np.arange(n_tasks)])
    batched = _BATCHED.get(statistic)
    if batched is not None:  # the same replicates, computed in one call
        reps = np.asarray(batched(*resampled), dtype=np.float64)
    else:
        reps = np.stack(
            [
                np.asarray(statistic(*(r[b] for r in resampled)), dtype=np.float64)
                for b in range(n_boot)
            ]
        )
    alpha = 1.0 - confidence
    if np.all(np.isfinite(point)) and np.all(np.isfinite(reps)):
        low, high = np.percentile(reps, [100 * alpha / 2, 100 * (1 - alpha / 2)], axis=0)
    else:
        low = high = np.full(point.shape, np.nan)
    return _scalar(point), _scalar(low), _scalar(high)


def _iqm_batch(replicates: Array) -> Array:
    """`iqm` of each ``(n_runs, n_tasks)`` replicate of an ``(n_boot, n_runs, n_tasks)`` stack."""
    flat = replicates.reshape(replicates.shape[0], -1)
    return np.asarray(sps.trim_mean(flat, 0.25, axis=1), dtype=np.float64)


def _iqm_columns(scores: Array) -> Array:
    """Per-task IQM (over the runs of each column): ``iqm(scores, axis=0)``."""
    return np.asarray(iqm(scores, axis=0), dtype=np.float64)


def _iqm_columns_batch(replicates: Array) -> Array:
    return np.asarray(sps.trim_mean(replicates, 0.25, axis=1), dtype=np.float64)


def iqm_ci(
    scores: npt.ArrayLike, n_boot: int = 2000, confidence: float = 0.95, seed: Seed = 0
) -> tuple[float, float, float]:
    """``(point, low, high)``: the IQM of all scores with its stratified bootstrap CI."""
    p, lo, hi = stratified_bootstrap_ci(scores, iqm, n_boot, confidence, seed)
    return float(p), float(lo), float(hi)


def iqm_columns_ci(
    scores: npt.ArrayLike, n_boot: int = 2000, confidence: float = 0.95, seed: Seed = 0
) -> tuple[Array, Array, Array]:
    """Per-column IQM of a runs × columns matrix (e.g. runs × checkpoints of a learning curve)
    with point-wise bootstrap bands (runs resampled within each column)."""
    p, lo, hi = stratified_bootstrap_ci(scores, _iqm_columns, n_boot, confidence, seed)
    return np.atleast_1d(p), np.atleast_1d(lo), np.atleast_1d(hi)


def stratified_bootstrap_ci(
    scores: npt.ArrayLike,
    statistic: Callable[[Array], Scalar] = iqm,
    n_boot: int = 2000,
    confidence: float = 0.95,
    seed: Seed = 0,
) -> tuple[Scalar, Scalar, Scalar]:
    """``(point, low, high)``: ``statistic(scores)`` and its stratified percentile bootstrap CI.

    ``scores`` has shape ``(n_runs, n_tasks)``. Each of ``n_boot`` replicates resamples the runs
    with replacement independently within every task column (Agarwal et al. 2021, §3 and
    App. A.4: "stratified bootstrap"), keeping the shape, and applies ``statistic`` to it; the
    interval is the ``(1 ± confidence)/2`` percentiles of the replicates. ``statistic`` may return
    a scalar or an array (then the bounds are element-wise). Deterministic for a given ``seed``.
    """
    return _bootstrap([_matrix(scores)], statistic, n_boot, confidence, seed)


def _poi(x: Array, y: Array, higher_is_better: bool) -> float:
    if x.shape[1] != y.shape[1]:
        raise ValueError(f"x and y have different task counts: {x.shape[1]} vs {y.shape[1]}")
    if not higher_is_better:
        x, y = -x, -y
    a, b = x[:, None, :], y[None, :, :]
    # Mann–Whitney U / (n m) per task: pairs with x > y count 1, ties 1/2.
    u = np.mean((a > b) + 0.5 * (a == b), axis=(0, 1))
    return float(np.mean(u))


def probability_of_improvement(
    x: npt.ArrayLike, y: npt.ArrayLike, higher_is_better: bool = True
) -> float:
    """P(X > Y): the probability that a run of method X beats a run of method Y on a task,
    averaged over tasks (Agarwal et al. 2021, §4, "probability of improvement").

    Per task it is the Mann–Whitney U statistic over all run pairs divided by ``n_x * n_y``, ties
    counting 1/2. ``x`` and ``y`` have shapes ``(n_runs_x, n_tasks)`` and ``(n_runs_y, n_tasks)``.
    With ``higher_is_better=False`` (errors, times) "beats" means a lower score, i.e. P(X < Y).
    """
    return _poi(_matrix(x), _matrix(y), higher_is_better)


def probability_of_improvement_ci(
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    higher_is_better: bool = True,
    n_boot: int = 2000,
    confidence: float = 0.95,
    seed: Seed = 0,
) -> tuple[float, float, float]:
    """``(point, low, high)`` of :func:`probability_of_improvement`, with a stratified bootstrap
    CI that resamples the runs of ``x`` and of ``y`` independently within each task."""
    p, lo, hi = _bootstrap(
        [_matrix(x), _matrix(y)],
        lambda a, b: _poi(a, b, higher_is_better),
        n_boot,
        confidence,
        seed,
    )
    return float(p), float(lo), float(hi)


def performance_profile(
    scores: npt.ArrayLike, thresholds: npt.ArrayLike, higher_is_better: bool = True
) -> Array:
    """Run-score distribution (Agarwal et al. 2021, §4, "performance profiles"): for each
    threshold τ, the fraction of the pooled scores with score > τ (score < τ when
    ``higher_is_better`` is False). With the same number of runs per task this equals rliable's
    average over tasks of the per-task fractions."""
    s = np.asarray(scores, dtype=np.float64).ravel()
    t = np.atleast_1d(np.asarray(thresholds, dtype=np.float64))
    hits = s[None, :] > t[:, None] if higher_is_better else s[None, :] < t[:, None]
    return np.asarray(np.mean(hits, axis=1), dtype=np.float64)


def performance_profile_ci(
    scores: npt.ArrayLike,
    thresholds: npt.ArrayLike,
    higher_is_better: bool = True,
    n_boot: int = 2000,
    confidence: float = 0.95,
    seed: Seed = 0,
) -> tuple[Array, Array, Array]:
    """``(profile, low, high)``: :func:`performance_profile` with a point-wise stratified
    bootstrap band (one array entry per threshold)."""
    p, lo, hi = stratified_bootstrap_ci(
        scores,
        lambda s: performance_profile(s, thresholds, higher_is_better),
        n_boot,
        confidence,
        seed,
    )
    return np.atleast_1d(p), np.atleast_1d(lo), np.atleast_1d(hi)


def _relative(proposed: Array, baseline: Array, higher_is_better: bool) -> float:
    p, b = float(iqm(proposed)), float(iqm(baseline))
    if b == 0.0 or not math.isfinite(b) or not math.isfinite(p):
        return math.nan
    return (p - b) / b if higher_is_better else (b - p) / b


def _relative_lower(proposed: Array, baseline: Array) -> float:
    return _relative(proposed, baseline, False)


def _relative_higher(proposed: Array, baseline: Array) -> float:
    return _relative(proposed, baseline, True)


def _relative_batch(proposed: Array, baseline: Array, higher_is_better: bool) -> Array:
    p, b = _iqm_batch(proposed), _iqm_batch(baseline)
    ok = (b != 0.0) & np.isfinite(b) & np.isfinite(p)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (p - b) / b if higher_is_better else (b - p) / b
    return np.where(ok, out, np.nan)


def relative_improvement_ci(
    proposed: npt.ArrayLike,
    baseline: npt.ArrayLike,
    higher_is_better: bool = False,
    n_boot: int = 2000,
    confidence: float = 0.95,
    seed: Seed = 0,
) -> tuple[float, float, float]:
    """``(point, low, high)`` of the relative improvement of the IQMs, positive when the proposed
    method is better: ``(baseline − proposed) / baseline`` for lower-is-better metrics (the
    default: errors, convergence times), ``(proposed − baseline) / baseline`` otherwise.

    The CI is a stratified bootstrap resampling both methods' runs independently per task. The
    point is nan when the baseline IQM is 0 or non-finite, and the bounds are nan when that happens
    in any replicate (docs/design.md §9: such a ratio is shown as "–").
    """
    p, lo, hi = _bootstrap(
        [_matrix(proposed), _matrix(baseline)],
        _relative_higher if higher_is_better else _relative_lower,
        n_boot,
        confidence,
        seed,
    )
    return float(p), float(lo), float(hi)


#: The words of :func:`verdict` (docs/design.md §9), in the order a reader scans them.
VERDICTS = ("consistent", "larger than claimed", "smaller than claimed", "refuted", "inconclusive")


def verdict(low: float, high: float, claimed: float) -> str:
    """Two-sided claim check (docs/design.md §9) of an improvement CI ``[low, high]`` against the
    claimed improvement size ``claimed`` (≥ 0, same sign convention: positive means the proposed
    method is better). The CI is closed; one of :data:`VERDICTS`:

    * ``"consistent"``: the CI lies above 0 and covers ``claimed`` (``0 < low ≤ claimed ≤ high``),
    * ``"larger than claimed"``: the CI lies entirely above ``claimed`` (``low > claimed``, and
      ``low > 0``),
    * ``"smaller than claimed"``: the CI lies between 0 and ``claimed``, exclusive of 0
      (``0 < low ≤ high < claimed``): the same direction, a smaller effect,
    * ``"refuted"``: the CI lies entirely below 0 (``high < 0``): the other direction,
    * ``"inconclusive"``: the CI contains 0 (``low ≤ 0 ≤ high``), or a bound is nan.

    A measured effect far above the claim is not a reproduction of its size, so it is not
    "consistent" either.
    """
    if not math.isfinite(claimed) or claimed < 0:
        raise ValueError(f"claimed must be a finite size >= 0, got {claimed}")
    if math.isnan(low) or math.isnan(high):
        return "inconclusive"
    if low > high:
        raise ValueError(f"low ({low}) > high ({high})")
    if high < 0:
        return "refuted"
    if low <= 0:
        return "inconclusive"
    if low > claimed:
        return "larger than claimed"
    if high < claimed:
        return "smaller than claimed"
    return "consistent"


#: Vectorised twins of statistics, applied to all replicates at once (same values as the loop).
_BATCHED: dict[Callable[..., Scalar], Callable[..., Array]] = {
    iqm: _iqm_batch,
    _iqm_columns: _iqm_columns_batch,
    _relative_lower: lambda p, b: _relative_batch(p, b, False),
    _relative_higher: lambda p, b: _relative_batch(p, b, True),
}
