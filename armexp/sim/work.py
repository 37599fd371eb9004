"""The closed loop's work buffer: one flat float64 array of scratch and the angle cache.

Layout (a single argument keeps the dispatch from Python cheap):
``[0]`` n, ``[1]`` cap (cached F rows), τ of the last step (n), the reference (3 × n: the
previous command, q̇_d at the current step's start and end), the link slots (3 × n: φ₀, cos,
sin), the τ_d slots (3 × n), the F-row slots (cap × `ROW`: φ₀, cos, sin, series), the two-link
row plan (cap × 8), then scratch (2n² + 24n). The compiled code works on 2-D views of the
blocks, indexed from 0, so no index needs numba's negative-index wraparound.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from armexp.sim.model import Array

#: F-term rows whose angles the default work buffer caches (rows beyond it use libm).
MAX_TERMS = 8
#: Start of τ of the last step (n entries), after n and cap.
TAU_START = 2
#: Columns of a cached F row: φ₀, cos φ₀, sin φ₀, then the series amp·cos(φ₀ + d) = Σ p_k d^k.
ROW = 11

#: The packed plant (`armexp.sim.model.Plant.packed`): weights, gravity coefficients, link
#: lengths, F terms, τ_d terms, torque limits.
Model = tuple[Array, Array, Array, Array, Array, Array]

#: numba ``fastmath`` flags of the loop's kernels: FMA contraction only, so results move by
#: rounding, never by reassociation, and NaN/inf checks stay.
FASTMATH = {"contract"}


@njit(cache=True)
def work_offsets(n: int, cap: int) -> tuple[int, int, int, int, int, int, int]:
    """Start of τ, reference, link slots, τ_d slots, F-row slots, row plan, scratch."""
    tau = TAU_START
    ref = tau + n
    links = ref + 3 * n
    dist = links + 3 * n
    rows = dist + 3 * n
    plan = rows + ROW * cap
    scratch = plan + 8 * cap
    return tau, ref, links, dist, rows, plan, scratch


@njit(cache=True)
def make_work(n: int, max_terms: int = MAX_TERMS) -> Array:
    """Scratch and angle cache for one closed loop, reused every step so the loop never allocates.

    ``max_terms`` F-term rows get cached angles; further rows are evaluated by libm.
    """
    work = np.zeros(work_offsets(n, max_terms)[6] + 2 * n * n + 24 * n)
    work[0] = n
    work[1] = max_terms
    clear_cache(work)
    return work


@njit(cache=True)
def clear_cache(work: Array) -> None:
    """Forget every cached angle: the next step evaluates all its slots by libm."""
    n = int(work[0])
    cap = int(work[1])
    _, _, links, dist, rows, _, _ = work_offsets(n, cap)
    for a in range(n):
        work[links + a] = np.nan
        work[dist + a] = np.nan
    for r in range(cap):
        work[rows + ROW * r] = np.nan
