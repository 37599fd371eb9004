"""Convergence as the paper defines it (Definition 1, eqs. 9–10), measured on a perturbed run.

Definition 1: the tracking error converges exponentially when, for some ᾱ ≥ 0, α > 0 and α* ≥ 0,

    ‖e(t)‖ ≤ ᾱ e^{−α (t − t0)} ‖e(t0)‖ + α*        for all t ≥ t0                 (9–10)

`definition_one` measures α (``decay_rate``, 1/s), α* (``ultimate_bound``, rad) and ᾱ
(``decay_overshoot``) on ‖e1(t)‖ of a run started with the reference ``offset`` rad from the arm on
every joint (docs/design.md §8), plus the ‖e1‖ settling time to the band max(2 % of the offset,
``tolerance``) and ITAE = ∫ (t − t0) ‖e1‖ dt, all over the first ``window`` seconds.

How the three constants are fitted, and why this way:

1. The non-increasing upper envelope E(t) = max_{s ≥ t} ‖e1(s)‖. Eq. 9 bounds ‖e‖ from above, so
   the fit follows the error's peaks: an oscillating decay (‖e1‖ dipping to 0 between swings) is
   measured by the peaks that bound it, and a trough never passes for convergence.
2. α* = max ‖e1‖ over the last quarter of the window (`TAIL_SHARE`): the smallest bound that holds
   once the transient is over, which is what eq. 10's ultimate bound is. It is the bound seen
   within the window; a decay slower than the window puts part of the transient into it.
3. α by least squares of log(E − α*) against t over the decaying part: from the envelope's peak
   until E − α* falls to `FIT_FLOOR` of its start, and no lower than `NOISE_FACTOR` × the
   step-to-step jitter of ‖e1‖ over the tail (its largest change between samples: where E − α*
   is mostly the noise of the steady error, its logarithm says nothing about the decay). The
   jitter, unlike the tail's spread, is not raised by a decay still under way in the tail. A
   straight line in log space weighs every decade of the decay alike, needs no starting guess
   and cannot fail to converge (unlike an iterative fit such as scipy's curve_fit on the raw
   error, which the first, largest samples dominate).
4. ᾱ = the smallest factor for which eq. 9 holds over the decaying part with the fitted α and α*:
   max (E(t) − α*) e^{α (t − t0)} / ‖e(t0)‖. It is 1 when the error decays from its start exactly
   as the exponential, above 1 when it first grows (overshoot) or decays in a slower phase.

NaN where a constant is not measurable: α and ᾱ of a run that starts inside its ultimate bound
(‖e1(t0)‖ ≤ α*: nothing to decay from) or whose decaying part has fewer than `MIN_POINTS` samples;
every quantity of an empty run. A run with a non-finite error (it diverged) has settling time inf
and NaN elsewhere. Quantities are taken over the samples inside the window; a run that ended
before the window's end is measured on what it has.
"""

from __future__ import annotations

import math

import numpy as np

from armexp.sim.metrics import BAND_FRACTION, convergence_time
from armexp.sim.model import Array

#: The share of the window at its end over which the ultimate bound α* is taken.
TAIL_SHARE = 0.25
#: The decay is fitted until the envelope's excess over α* falls to this share of its start.
FIT_FLOOR = 0.02
#: ... and no lower than this many times the jitter of ‖e1‖ over the tail (its noise).
NOISE_FACTOR = 10.0
#: Fewest samples in the decaying part for a rate.
MIN_POINTS = 3
#: The names of `definition_one`'s results.
KEYS = ("decay_rate", "ultimate_bound", "decay_overshoot", "settling_time", "itae")


def definition_one(
    t: Array, norm_e1: Array, offset: float, window: float, tolerance: float
) -> dict[str, float]:
    """Definition 1's constants of a perturbed run, with its settling time and ITAE.

    Args:
        t: Sample times (s), increasing; t[0] is t0, the perturbation's start.
        norm_e1: ‖e1‖ = ‖q − q_d‖ at those times (rad).
        offset: The reference offset of the run (rad, per joint): the settling band is
            max(2 % of it, ``tolerance``).
        window: Seconds from t0 over which everything is measured.
        tolerance: The settling band's floor (rad).

    Returns:
        ``decay_rate`` α (1/s), ``ultimate_bound`` α* (rad), ``decay_overshoot`` ᾱ,
        ``settling_time`` (s from t0; inf when ‖e1‖ ends outside the band) and ``itae``
        (rad·s², trapezoidal rule). See the module docstring for the method.
    """
    t = np.asarray(t, dtype=np.float64)
    e = np.asarray(norm_e1, dtype=np.float64)
    if t.ndim != 1 or t.shape != e.shape:
        raise ValueError(f"t and norm_e1 must be 1-d of one length, got {t.shape} and {e.shape}")
    if not (window > 0 and offset > 0 and tolerance >= 0):
        raise ValueError(
            f"window and offset must be > 0 and tolerance ≥ 0, got {window}, {offset}, {tolerance}"
        )
    out = dict.fromkeys(KEYS, math.nan)
    if t.size == 0:
        return out
    inside = (t - t[0]) < window - 1e-9
    t, e = t[inside], e[inside]
    if not np.all(np.isfinite(e)):
        out["settling_time"] = math.inf
        return out
    rel = t - t[0]
    band = max(BAND_FRACTION * offset, tolerance)
    out["settling_time"] = convergence_time(rel, e, band)
    out["itae"] = float(np.trapezoid(rel * e, rel)) if t.size > 1 else 0.0
    tail = rel >= (1.0 - TAIL_SHARE) * rel[-1]
    bound = float(e[tail].max())
    out["ultimate_bound"] = bound
    jitter = float(np.abs(np.diff(e[tail])).max()) if tail.sum() > 1 else 0.0
    out.update(_decay(rel, e, bound, jitter))
    return out


def upper_envelope(norm_e1: Array) -> Array:
    """E[i] = max over j ≥ i of ``norm_e1[j]``: non-increasing, above the error everywhere."""
    return np.maximum.accumulate(np.asarray(norm_e1, dtype=np.float64)[::-1])[::-1]


def _decay(rel: Array, e: Array, bound: float, jitter: float) -> dict[str, float]:
    """α and ᾱ of the decaying part (times ``rel`` from t0), given α* = ``bound``."""
    nan = {"decay_rate": math.nan, "decay_overshoot": math.nan}
    e0 = float(e[0])
    if not e0 > bound:
        return nan  # starts inside its ultimate bound
    envelope = upper_envelope(e)
    excess = envelope - bound
    peak = int(np.argmax(e))
    floor = max(FIT_FLOOR * float(excess[peak]), NOISE_FACTOR * jitter)
    above = np.nonzero(excess[peak:] > floor)[0]
    if above.size == 0:
        return nan
    part = slice(peak, peak + int(above[-1]) + 1)
    x, y = rel[part], np.log(excess[part])
    if x.size < MIN_POINTS or x[-1] <= x[0]:
        return nan
    slope = float(np.polyfit(x, y, 1)[0])
    rate = max(-slope, 0.0)
    overshoot = float(np.max(excess[part] * np.exp(rate * x)) / e0)
    return {"decay_rate": rate, "decay_overshoot": overshoot}
