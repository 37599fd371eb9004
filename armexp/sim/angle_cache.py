"""The angle cache: cos and sin of angles that move a little each step, by Taylor series.

Every angle the plant takes a cosine or sine of is linear in (q, q̇, t): the absolute link
angles θ_a, the F-term arguments freq·q_j or freq·q̇_j, and τ_d's freq·t. The work buffer
(`armexp.sim.work`) keeps, for each of these "slots", the angle φ₀ at the current step's start
with cos φ₀ and sin φ₀. Any other angle φ = φ₀ + δ of the slot (an RK4 stage, the next step's
start) comes from the Taylor series of cos and sin about φ₀: degree 5 up to |δ| = `ROTATE_SHORT`,
degree 7 up to `ROTATE_MAX` (truncation < 2.2e-17). libm is called instead when
|δ| > `ROTATE_MAX`, and for every slot at each step index that is a multiple of `ANCHOR_PERIOD`
or when the buffer is fresh (`armexp.sim.work.make_work`, `armexp.sim.work.clear_cache`), so
rounding cannot accumulate over more than 64 steps. As φ₀ is stored with its cosine and sine,
the result is right for any state (a reset, an edited state, another model): the cache only
decides how cos φ is computed. The rule depends on the step index and the buffer alone, so one
long `armexp.sim.simulator.advance` and many short ones give bit-identical trajectories.
"""

from __future__ import annotations

import math

from numba import njit

from armexp.sim.model import Array
from armexp.sim.work import FASTMATH

#: Every slot's cosine and sine are recomputed by libm at step indices that are multiples of this
#: (a power of two).
ANCHOR_PERIOD = 64
#: ``k & ANCHOR_MASK == 0`` marks an anchor step k.
ANCHOR_MASK = ANCHOR_PERIOD - 1
#: Largest angle step |δ| (rad) taken from the Taylor series rather than libm.
ROTATE_MAX = 1.0 / 32.0
#: Up to this |δ| (rad) the series stops at degree 5 (truncation < 5e-18), beyond it at degree 7.
ROTATE_SHORT = 1.0 / 256.0

# Taylor coefficients of cos and sin (1/k! with signs folded where used).
_M2 = -0.5
_I6 = 1.0 / 6.0
_I24 = 1.0 / 24.0
_I120 = 1.0 / 120.0
_M720 = -1.0 / 720.0
_I5040 = 1.0 / 5040.0


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def series(c: float, s: float, d: float) -> tuple[float, float]:
    """(cos, sin)(φ₀ + d) from (cos, sin)(φ₀) by the Taylor series in d, |d| ≤ ROTATE_MAX.

    Degree 5 for |d| ≤ ROTATE_SHORT, else degree 7 (Estrin form): truncation < 2.2e-17.
    """
    d2 = d * d
    cl = (c - s * d) + d2 * (_M2 * c + (_I6 * s) * d)
    sl = (s + c * d) + d2 * (_M2 * s - (_I6 * c) * d)
    ch = _I24 * c - (_I120 * s) * d
    sh = _I24 * s + (_I120 * c) * d
    if abs(d) > ROTATE_SHORT:
        ch += d2 * (_M720 * c + (_I5040 * s) * d)
        sh += d2 * (_M720 * s - (_I5040 * c) * d)
    d4 = d2 * d2
    return cl + d4 * ch, sl + d4 * sh


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def turn(phi: float, phi0: float, c0: float, s0: float) -> tuple[float, float]:
    """(cos φ, sin φ) from the cached φ₀, or by libm when φ is far from it (or φ₀ is NaN)."""
    d = phi - phi0
    if abs(d) <= ROTATE_MAX:
        return series(c0, s0, d)
    return math.cos(phi), math.sin(phi)


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def turn_by(d: float, phi: float, c0: float, s0: float) -> tuple[float, float]:
    """(cos φ, sin φ) for φ = φ₀ + d, given d directly (an RK4 stage's offset from the base)."""
    if abs(d) <= ROTATE_MAX:
        return series(c0, s0, d)
    return math.cos(phi), math.sin(phi)


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def poly7(rows: Array, p: int, d: float) -> float:
    """Row p's series Σ_k p_k d^k (k ≤ 5 for |d| ≤ ROTATE_SHORT, else k ≤ 7; Estrin form)."""
    d2 = d * d
    lo = (rows[p, 3] + rows[p, 4] * d) + d2 * (rows[p, 5] + rows[p, 6] * d)
    hi = rows[p, 7] + rows[p, 8] * d
    if abs(d) > ROTATE_SHORT:
        hi += d2 * (rows[p, 9] + rows[p, 10] * d)
    return lo + (d2 * d2) * hi


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def store_row(rows: Array, p: int, phi: float, c: float, s: float, amp: float) -> None:
    """Cache row p's angle at the step's start and its series amp·cos(φ₀ + d) = Σ p_k d^k."""
    rows[p, 0] = phi
    rows[p, 1] = c
    rows[p, 2] = s
    ac = amp * c
    sa = amp * s
    rows[p, 3] = ac
    rows[p, 4] = -sa
    rows[p, 5] = _M2 * ac
    rows[p, 6] = _I6 * sa
    rows[p, 7] = _I24 * ac
    rows[p, 8] = -_I120 * sa
    rows[p, 9] = _M720 * ac
    rows[p, 10] = _I5040 * sa
