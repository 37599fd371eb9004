"""The compiled closed loop: controller + RK4 plant at the controller period (DESIGN.md §3).

Per controller step k (t_k = k·dt):

1. u ~ U(0,1) for τ_d is drawn for this period (`armexp.sim.noise`).
2. The controller computes τ from the measured state and M(q); τ is held over the step.
3. The plant q̈ = M⁻¹(τ − C q̇ − G) + F + τ_d(t) (eq. 2) advances by classic RK4.
4. q_d integrates q̇_d exactly; q̇_d comes from the reference generator (`_reference`: a ramp
   from the previous command to the new one across the command's period, or a hold). ρ̂ (eq. 12)
   and the PID integral (with anti-windup at the torque limit) advance by explicit Euler.

The closed-loop state is one float vector ``[q, q̇, q_d, ∫e1 dt, ρ̂]`` (length 4n + 1).
`advance` runs k steps in one call (one environment step is 30 of them); `simulate_batch` runs
many gain candidates × reference scenarios in parallel for the tuner.

Speed. Every angle the plant takes a cosine or sine of is linear in (q, q̇, t): the absolute link
angles θ_a, the F-term arguments freq·q_j or freq·q̇_j, and τ_d's freq·t. The work buffer keeps,
for each of these "slots", the angle φ₀ at the current step's start with cos φ₀ and sin φ₀. Any
other angle φ = φ₀ + δ of the slot (an RK4 stage, the next step's start) comes from the Taylor
series of cos and sin about φ₀: degree 5 up to |δ| = `ROTATE_SHORT`, degree 7 up to `ROTATE_MAX`
(truncation < 2.2e-17). libm is called instead when |δ| > `ROTATE_MAX`, and for every slot at
each step index that is a multiple of `ANCHOR_PERIOD` or when the buffer is fresh (`make_work`,
`clear_cache`), so rounding cannot accumulate over more than 64 steps. As φ₀ is stored with its
cosine and sine, the result is right for any state (a reset, an edited state, another model): the
cache only decides how cos φ is computed. The rule depends on the step index and the buffer
alone, so one long `advance` and many short ones give bit-identical trajectories.

The two-link arm has an unrolled path (scalars, closed-form 2×2 solve with one division, the bias
written as K + A ω₀² + B ω₁² so a stage waits for its velocity only through two multiply-adds);
other n use generic loops and a Cholesky solve. Both use the same angle cache.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from armexp.sim.controllers import KINDS, PID, control
from armexp.sim.dynamics import absolute_angles, cholesky_solve, mass_and_bias_cs, tip_position
from armexp.sim.model import SOURCE_Q, Array, Plant
from armexp.sim.noise import stream_key, uniform

#: Above this joint speed (rad/s) a run counts as diverged; no physical arm gets near it.
DIVERGENCE_SPEED = 1e4
#: Every slot's cosine and sine are recomputed by libm at step indices that are multiples of this
#: (a power of two).
ANCHOR_PERIOD = 64
#: Largest angle step |δ| (rad) taken from the Taylor series rather than libm.
ROTATE_MAX = 1.0 / 32.0
#: Up to this |δ| (rad) the series stops at degree 5 (truncation < 5e-18), beyond it at degree 7.
ROTATE_SHORT = 1.0 / 256.0
#: F-term rows whose angles the default work buffer caches (rows beyond it use libm).
MAX_TERMS = 8

Model = tuple[Array, Array, Array, Array, Array, Array]

# FMA contraction only: results move by rounding, never by reassociation, and NaN/inf checks stay.
_FAST = {"contract"}
# The two run loops are compiled with numba's ``_nrt=False``: they allocate nothing, and without
# it every array view handed to an inlined helper costs an atomic reference-count pair per step
# (measured: 222 instead of 120 ns per two-link step).
_ANCHOR_MASK = ANCHOR_PERIOD - 1
# Taylor coefficients of cos and sin (1/k! with signs folded where used).
_M2 = -0.5
_I6 = 1.0 / 6.0
_I24 = 1.0 / 24.0
_I120 = 1.0 / 120.0
_M720 = -1.0 / 720.0
_I5040 = 1.0 / 5040.0
# Columns of a cached F row: φ₀, cos φ₀, sin φ₀, then the series amp·cos(φ₀ + d) = Σ p_k d^k.
_ROW = 11


#: Reference generators (DESIGN §4): q̇_d ramps linearly from the previous command to the new
#: one across each command's period (first-order hold), or jumps to it (zero-order hold).
REFERENCES = ("ramp", "hold")


def trajectory_columns(n: int) -> list[str]:
    """Column names of a logged trajectory (the `trajectory.parquet` contract).

    ``tau_<j>`` is the torque the plant received (after saturation); ``sat_<j>`` is 1.0 when it
    was at the torque limit during that step.
    """
    j = range(1, n + 1)
    return (
        ["t"]
        + [f"q_{i}" for i in j]
        + [f"q_d_{i}" for i in j]
        + [f"dq_{i}" for i in j]
        + [f"dq_d_{i}" for i in j]
        + [f"tau_{i}" for i in j]
        + ["rho_hat", "tip_x", "tip_y"]
        + [f"sat_{i}" for i in j]
    )


def log_width(n: int) -> int:
    """Number of `trajectory_columns`."""
    return 4 + 6 * n


# --- work buffer -------------------------------------------------------------------------------
# One flat float64 array (a single argument keeps the dispatch from Python cheap):
#   [0] n, [1] cap (cached F rows), τ of the last step (n), the reference (3 × n: the previous
#   command, q̇_d at the current step's start and end), the link slots (3 × n: φ₀, cos, sin),
#   the τ_d slots (3 × n), the F-row slots (cap × 11: φ₀, cos, sin, series), the two-link row
#   plan (cap × 8), then scratch (2n² + 24n). The compiled code works on 2-D views of the blocks,
#   indexed from 0, so no index needs numba's negative-index wraparound.


@njit(cache=True)
def _offsets(n: int, cap: int) -> tuple[int, int, int, int, int, int, int]:
    """Start of τ, reference, link slots, τ_d slots, F-row slots, row plan, scratch."""
    tau = 2
    ref = tau + n
    links = ref + 3 * n
    dist = links + 3 * n
    rows = dist + 3 * n
    plan = rows + _ROW * cap
    scratch = plan + 8 * cap
    return tau, ref, links, dist, rows, plan, scratch


@njit(cache=True)
def make_work(n: int, max_terms: int = MAX_TERMS) -> Array:
    """Scratch and angle cache for one closed loop, reused every step so the loop never allocates.

    ``max_terms`` F-term rows get cached angles; further rows are evaluated by libm.
    """
    work = np.zeros(_offsets(n, max_terms)[6] + 2 * n * n + 24 * n)
    work[0] = n
    work[1] = max_terms
    clear_cache(work)
    return work


@njit(cache=True)
def clear_cache(work: Array) -> None:
    """Forget every cached angle: the next step evaluates all its slots by libm."""
    n = int(work[0])
    cap = int(work[1])
    _, _, links, dist, rows, _, _ = _offsets(n, cap)
    for a in range(n):
        work[links + a] = np.nan
        work[dist + a] = np.nan
    for r in range(cap):
        work[rows + _ROW * r] = np.nan


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _series(c: float, s: float, d: float) -> tuple[float, float]:
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


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _turn(phi: float, phi0: float, c0: float, s0: float) -> tuple[float, float]:
    """(cos φ, sin φ) from the cached φ₀, or by libm when φ is far from it (or φ₀ is NaN)."""
    d = phi - phi0
    if abs(d) <= ROTATE_MAX:
        return _series(c0, s0, d)
    return math.cos(phi), math.sin(phi)


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _turn_by(d: float, phi: float, c0: float, s0: float) -> tuple[float, float]:
    """(cos φ, sin φ) for φ = φ₀ + d, given d directly (an RK4 stage's offset from the base)."""
    if abs(d) <= ROTATE_MAX:
        return _series(c0, s0, d)
    return math.cos(phi), math.sin(phi)


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _poly7(rows: Array, p: int, d: float) -> float:
    """Row p's series Σ_k p_k d^k (k ≤ 5 for |d| ≤ ROTATE_SHORT, else k ≤ 7; Estrin form)."""
    d2 = d * d
    lo = (rows[p, 3] + rows[p, 4] * d) + d2 * (rows[p, 5] + rows[p, 6] * d)
    hi = rows[p, 7] + rows[p, 8] * d
    if abs(d) > ROTATE_SHORT:
        hi += d2 * (rows[p, 9] + rows[p, 10] * d)
    return lo + (d2 * d2) * hi


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _store_row(rows: Array, p: int, phi: float, c: float, s: float, amp: float) -> None:
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


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _base_rows(state: Array, n: int, anchor: bool, f_terms: Array, rows: Array) -> None:
    """Move the cached F-row slots (row r in slot r) to the step's start."""
    for r in range(rows.shape[0]):
        src = int(f_terms[r, 4])
        x = state[src] if int(f_terms[r, 3]) == SOURCE_Q else state[n + src]
        phi = f_terms[r, 2] * x
        if anchor:
            c = math.cos(phi)
            s = math.sin(phi)
        else:
            c, s = _turn(phi, rows[r, 0], rows[r, 1], rows[r, 2])
        _store_row(rows, r, phi, c, s, f_terms[r, 1])


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _base_dist(t: float, anchor: bool, dist: Array, slots: Array) -> None:
    """Move the τ_d slots (3 × n: φ₀, cos, sin) to the step's start."""
    for i in range(slots.shape[1]):
        if dist[0, i] != 0.0:
            phi = dist[1, i] * t
            if anchor:
                c = math.cos(phi)
                s = math.sin(phi)
            else:
                c, s = _turn(phi, slots[0, i], slots[1, i], slots[2, i])
            slots[0, i] = phi
            slots[1, i] = c
            slots[2, i] = s


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _disturbance(key: np.uint64, k: int, dist: Array, rot: Array, slots: Array, ext: Array) -> None:
    """τ_d of step k at its start, half step and end into ext rows 0, 1, 2 (3 × n).

    ``rot`` holds cos, sin of freq·dt/2 and of freq·dt per joint (rows 0–3).
    """
    n = slots.shape[1]
    for i in range(n):
        noise = dist[2, i] * uniform(key, k, i, n) if dist[2, i] != 0.0 else 0.0
        amp = dist[0, i]
        if amp != 0.0:
            c = slots[1, i]
            s = slots[2, i]
            ext[0, i] = amp * c + noise
            ext[1, i] = amp * (c * rot[0, i] - s * rot[1, i]) + noise
            ext[2, i] = amp * (c * rot[2, i] - s * rot[3, i]) + noise
        else:
            ext[0, i] = noise
            ext[1, i] = noise
            ext[2, i] = noise


@njit(cache=True)
def _rotations(dist: Array, dt: float, rot: Array) -> None:
    for i in range(dist.shape[1]):
        w = dist[1, i] * dt
        rot[0, i] = math.cos(0.5 * w)
        rot[1, i] = math.sin(0.5 * w)
        rot[2, i] = math.cos(w)
        rot[3, i] = math.sin(w)


@njit(cache=True)
def _log_row(row: Array, t: float, state: Array, dqd: Array, n: int, lengths: Array) -> None:
    row[0] = t
    for i in range(n):
        row[1 + i] = state[i]
        row[1 + n + i] = state[2 * n + i]
        row[1 + 2 * n + i] = state[n + i]
        row[1 + 3 * n + i] = dqd[i]
    row[1 + 5 * n] = state[4 * n]
    x, y = tip_position(state[0:n], lengths)
    row[2 + 5 * n] = x
    row[3 + 5 * n] = y


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _reference(
    ramp: bool, cmd: Array, prev: Array, j: int, hold: int, now: Array, end: Array
) -> None:
    """q̇_d at the start (``now``) and end (``end``) of step j of a command held ``hold`` steps.

    ramp: q̇_d moves linearly from ``prev`` to ``cmd`` across the hold, so q̈_d = Δcommand /
    period; hold: q̇_d = ``cmd`` throughout. q_d integrates the segment exactly (trapezoid).
    """
    if ramp:
        f0 = j / hold
        f1 = (j + 1) / hold
        for i in range(now.shape[0]):
            d = cmd[i] - prev[i]
            now[i] = prev[i] + d * f0
            end[i] = prev[i] + d * f1
    else:
        for i in range(now.shape[0]):
            now[i] = cmd[i]
            end[i] = cmd[i]


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _integrate_reference(state: Array, now: Array, end: Array, h: float, n: int) -> None:
    """q_d += ∫ q̇_d over the step (exact for the linear segment; h·q̇_d under a hold)."""
    for i in range(n):
        state[2 * n + i] += h * (0.5 * (now[i] + end[i]))


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _integrate_error(
    kind: int, state: Array, e1: Array, tau: Array, tau_limit: Array, h: float, n: int
) -> None:
    """∫e1 dt by explicit Euler, with the PID's anti-windup: a joint whose torque is at the limit
    does not integrate the error that would drive it further into saturation."""
    for i in range(n):
        if kind == PID and abs(tau[i]) >= tau_limit[i] and e1[i] * tau[i] < 0.0:
            continue
        state[3 * n + i] += h * e1[i]


@njit(cache=True, inline="always")
def _log_torque(row: Array, tau: Array, tau_limit: Array, n: int) -> None:
    """The applied torque and the saturation flag of a logged step."""
    for i in range(n):
        row[1 + 4 * n + i] = tau[i]
        row[4 + 5 * n + i] = 1.0 if abs(tau[i]) >= tau_limit[i] else 0.0


@njit(cache=True)
def _diverged(state: Array, n: int) -> bool:
    for i in range(2 * n):
        x = state[i]
        if not np.isfinite(x):
            return True
    for i in range(n, 2 * n):
        if abs(state[i]) > DIVERGENCE_SPEED:
            return True
    return not np.isfinite(state[4 * n])


# --- two-link path -----------------------------------------------------------------------------


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _solve_two(
    c0: float,
    s0: float,
    c1: float,
    s1: float,
    tau0: float,
    tau1: float,
    w00: float,
    w01: float,
    w11: float,
    g0: float,
    g1: float,
) -> tuple[float, float, float, float, float, float]:
    """M⁻¹(τ − C q̇ − G) for n = 2 as K + A ω₀² + B ω₁² (ω = θ̇): returns K0, K1, A0, B0, A1, B1.

    With c₁₂ = cos(θ₀ − θ₁), M = [[W₀₀ + W₁₁ + 2W₀₁c₁₂, W₁₁ + W₀₁c₁₂], [·, W₁₁]] and
    det M = W₀₀W₁₁ − (W₀₁c₁₂)²; the bias C q̇ = Aᵀ h_θ is linear in ω², so the part of the solve
    that waits for the stage velocity is two multiply-adds.
    """
    c12 = c0 * c1 + s0 * s1
    s12 = s0 * c1 - c0 * s1
    wc = w01 * c12
    m00 = (w00 + w11) + 2.0 * wc
    m01 = w11 + wc
    inv = 1.0 / (w00 * w11 - wc * wc)
    gc1 = g1 * c1
    r0 = tau0 - (g0 * c0 + gc1)
    r1 = tau1 - gc1
    k0 = (w11 * r0 - m01 * r1) * inv
    k1 = (m00 * r1 - m01 * r0) * inv
    wsi = (w01 * s12) * inv
    return k0, k1, -wsi * wc, -wsi * w11, wsi * (w00 + wc), wsi * m01


@njit(cache=True)
def _plan_two(f_terms: Array, plan: Array, m: int) -> int:
    """Fill the two-link F-row plan for the first m rows; returns how many depend on q.

    Plan row p (cache slot p) is [u_q0, u_q1, u_v0, u_v1, j0, j1, row, amp], with the row's angle
    φ = u · (q, q̇) (one entry of u is the frequency, the others 0) and j its 0/1 joint mask. Rows
    on q come first; the rows on q̇, which wait for the latest stage acceleration, last.
    """
    p = 0
    m_q = 0
    for on_q in (True, False):
        for r in range(m):
            if (int(f_terms[r, 3]) == SOURCE_Q) != on_q:
                continue
            for j in range(6):
                plan[p, j] = 0.0
            src = int(f_terms[r, 4])
            plan[p, src if on_q else 2 + src] = f_terms[r, 2]
            plan[p, 4 + int(f_terms[r, 0])] = 1.0
            plan[p, 6] = r
            plan[p, 7] = f_terms[r, 1]
            p += 1
        if on_q:
            m_q = p
    return m_q


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _base_rows_two(
    q0: float, q1: float, v0: float, v1: float, anchor: bool, plan: Array, rows: Array
) -> tuple[float, float]:
    """Move the two-link F-row slots to the step's start; returns F there."""
    f0 = 0.0
    f1 = 0.0
    for p in range(plan.shape[0]):
        phi = (plan[p, 0] * q0 + plan[p, 1] * q1) + (plan[p, 2] * v0 + plan[p, 3] * v1)
        if anchor:
            c = math.cos(phi)
            s = math.sin(phi)
        else:
            c, s = _turn(phi, rows[p, 0], rows[p, 1], rows[p, 2])
        amp = plan[p, 7]
        _store_row(rows, p, phi, c, s, amp)
        f0 += plan[p, 4] * (amp * c)
        f1 += plan[p, 5] * (amp * c)
    return f0, f1


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _stage_rows_two(
    fr: float,
    kv0: float,
    kv1: float,
    ka0: float,
    ka1: float,
    qs0: float,
    qs1: float,
    vs0: float,
    vs1: float,
    plan: Array,
    rows: Array,
) -> tuple[float, float]:
    """F of the given plan rows at an RK4 stage, from the step's series (or libm)."""
    f0 = 0.0
    f1 = 0.0
    for p in range(plan.shape[0]):
        d = ((fr * plan[p, 0]) * kv0 + (fr * plan[p, 1]) * kv1) + (
            (fr * plan[p, 3]) * ka1 + (fr * plan[p, 2]) * ka0
        )
        if abs(d) <= ROTATE_MAX:
            val = _poly7(rows, p, d)
        else:
            phi = (plan[p, 0] * qs0 + plan[p, 1] * qs1) + (plan[p, 2] * vs0 + plan[p, 3] * vs1)
            val = plan[p, 7] * math.cos(phi)
        f0 += plan[p, 4] * val
        f1 += plan[p, 5] * val
    return f0, f1


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _extra_rows(
    x0: float, x1: float, x2: float, x3: float, f_terms: Array, first: int
) -> tuple[float, float]:
    """F of the rows beyond the cache (from ``first`` on) by libm, at (q, q̇) = (x0, x1, x2, x3)."""
    f0 = 0.0
    f1 = 0.0
    for r in range(first, f_terms.shape[0]):
        src = int(f_terms[r, 4])
        x = (x0 if src == 0 else x1) if int(f_terms[r, 3]) == SOURCE_Q else x2 if src == 0 else x3
        val = f_terms[r, 1] * math.cos(f_terms[r, 2] * x)
        if int(f_terms[r, 0]) == 0:
            f0 += val
        else:
            f1 += val
    return f0, f1


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _stage_two(
    fr: float,
    kv0: float,
    kv1: float,
    ka0: float,
    ka1: float,
    q0: float,
    q1: float,
    v0: float,
    v1: float,
    bc0: float,
    bs0: float,
    bc1: float,
    bs1: float,
    tau0: float,
    tau1: float,
    w00: float,
    w01: float,
    w11: float,
    g0: float,
    g1: float,
    ext0: float,
    ext1: float,
    f_terms: Array,
    plan_q: Array,
    rows_q: Array,
    plan_v: Array,
    rows_v: Array,
) -> tuple[float, float, float, float]:
    """One RK4 stage of the two-link arm at (q + fr·kv, q̇ + fr·ka): (stage q̇, stage q̈)."""
    dq0 = fr * kv0
    dq1 = fr * kv1
    qs0 = q0 + dq0
    qs1 = q1 + dq1
    vs0 = v0 + fr * ka0
    vs1 = v1 + fr * ka1
    c0, s0 = _turn_by(dq0, qs0, bc0, bs0)
    c1, s1 = _turn_by(dq0 + dq1, qs0 + qs1, bc1, bs1)
    k0, k1, p0, r0, p1, r1 = _solve_two(c0, s0, c1, s1, tau0, tau1, w00, w01, w11, g0, g1)
    fq0, fq1 = _stage_rows_two(fr, kv0, kv1, ka0, ka1, qs0, qs1, vs0, vs1, plan_q, rows_q)
    m = plan_q.shape[0] + plan_v.shape[0]
    if f_terms.shape[0] > m:
        x0, x1 = _extra_rows(qs0, qs1, vs0, vs1, f_terms, m)
        fq0 += x0
        fq1 += x1
    fv0, fv1 = _stage_rows_two(fr, kv0, kv1, ka0, ka1, qs0, qs1, vs0, vs1, plan_v, rows_v)
    ww0 = vs0 * vs0
    ww1 = (vs0 + vs1) * (vs0 + vs1)
    a0 = ((k0 + (fq0 + ext0)) + p0 * ww0 + r0 * ww1) + fv0
    a1 = ((k1 + (fq1 + ext1)) + p1 * ww0 + r1 * ww1) + fv1
    return vs0, vs1, a0, a1


@njit(cache=True, error_model="numpy", fastmath=_FAST, _nrt=False)  # type: ignore[call-overload]
def _run_two(
    state: Array,
    commands: Array,
    hold: int,
    k0: int,
    kind: int,
    gains: Array,
    model: Model,
    dt: float,
    key: np.uint64,
    work: Array,
    log: Array,
    trace: Array,
    ramp: bool,
) -> tuple[int, bool]:
    """`_run` for n = 2, unrolled: the whole RK4 step lives in scalars."""
    n = 2
    weights, gcoef, lengths, f_terms, dist, tau_limit = model
    cap = int(work[1])
    tb, fb, lb, db, rb, pb, sb = _offsets(n, cap)
    tau = work[tb : tb + n]
    prev = work[fb : fb + n]
    dqd = work[fb + n : fb + 2 * n]
    dqd_end = work[fb + 2 * n : fb + 3 * n]
    links = work[lb : lb + 3 * n].reshape((3, n))
    dslots = work[db : db + 3 * n].reshape((3, n))
    rows = work[rb : rb + _ROW * cap].reshape((cap, _ROW))
    plan = work[pb : pb + 8 * cap].reshape((cap, 8))
    mass = work[sb : sb + 4].reshape((2, 2))
    e1 = work[sb + 4 : sb + 6]
    y2 = work[sb + 6 : sb + 8]
    ext = work[sb + 8 : sb + 14].reshape((3, 2))
    rot = work[sb + 14 : sb + 22].reshape((4, 2))
    _rotations(dist, dt, rot)
    n_rows = f_terms.shape[0]
    m = min(n_rows, cap)
    m_q = _plan_two(f_terms, plan, m)
    plan_m = plan[:m]
    rows_m = rows[:m]
    plan_q = plan[:m_q]
    rows_q = rows[:m_q]
    plan_v = plan[m_q:m]
    rows_v = rows[m_q:m]
    w00 = weights[0, 0]
    w01 = weights[0, 1]
    w11 = weights[1, 1]
    g0 = gcoef[0]
    g1 = gcoef[1]
    h = dt
    hh = 0.5 * dt
    h6 = dt / 6.0
    record = log.shape[0] > 0
    tracing = trace.shape[0] > 0
    steps = 0
    for ci in range(commands.shape[0]):
        cmd = commands[ci]
        for j in range(hold):
            k = k0 + steps
            t = k * dt
            _reference(ramp, cmd, prev, j, hold, dqd, dqd_end)
            if record:
                _log_row(log[steps], t, state, dqd, n, lengths)
            if tracing:
                trace[steps, 0] = state[0] - state[4]
                trace[steps, 1] = state[1] - state[5]
            q0 = state[0]
            q1 = state[1]
            v0 = state[2]
            v1 = state[3]
            # Slots at the step's start: θ₀ = q₀, θ₁ = q₀ + q₁, the F rows, τ_d.
            anchor = (k & _ANCHOR_MASK) == 0
            th1 = q0 + q1
            if anchor:
                bc0 = math.cos(q0)
                bs0 = math.sin(q0)
                bc1 = math.cos(th1)
                bs1 = math.sin(th1)
            else:
                bc0, bs0 = _turn(q0, links[0, 0], links[1, 0], links[2, 0])
                bc1, bs1 = _turn(th1, links[0, 1], links[1, 1], links[2, 1])
            links[0, 0] = q0
            links[1, 0] = bc0
            links[2, 0] = bs0
            links[0, 1] = th1
            links[1, 1] = bc1
            links[2, 1] = bs1
            fq0, fq1 = _base_rows_two(q0, q1, v0, v1, anchor, plan_m, rows_m)
            if n_rows > m:
                x0, x1 = _extra_rows(q0, q1, v0, v1, f_terms, m)
                fq0 += x0
                fq1 += x1
            _base_dist(t, anchor, dist, dslots)
            _disturbance(key, k, dist, rot, dslots, ext)
            # M(q) at the step's start, shared by the controller and RK4 stage 1.
            wc = w01 * (bc0 * bc1 + bs0 * bs1)
            mass[0, 0] = (w00 + w11) + 2.0 * wc
            mass[0, 1] = w11 + wc
            mass[1, 0] = w11 + wc
            mass[1, 1] = w11
            rho_dot = control(kind, gains, state, dqd, mass, tau_limit, tau, e1, y2)
            tau0 = tau[0]
            tau1 = tau[1]
            kk0, kk1, p0, r0, p1, r1 = _solve_two(
                bc0, bs0, bc1, bs1, tau0, tau1, w00, w01, w11, g0, g1
            )
            ww0 = v0 * v0
            ww1 = (v0 + v1) * (v0 + v1)
            a0 = (kk0 + (fq0 + ext[0, 0])) + p0 * ww0 + r0 * ww1
            a1 = (kk1 + (fq1 + ext[0, 1])) + p1 * ww0 + r1 * ww1
            sv0 = v0
            sv1 = v1
            sa0 = a0
            sa1 = a1
            kv0 = v0
            kv1 = v1
            for st in range(3):
                fr = hh if st < 2 else h
                e = 1 if st < 2 else 2
                kv0, kv1, a0, a1 = _stage_two(
                    fr, kv0, kv1, a0, a1, q0, q1, v0, v1, bc0, bs0, bc1, bs1, tau0, tau1,
                    w00, w01, w11, g0, g1, ext[e, 0], ext[e, 1], f_terms,
                    plan_q, rows_q, plan_v, rows_v,
                )  # fmt: skip
                wt = 2.0 if st < 2 else 1.0
                sv0 += wt * kv0
                sv1 += wt * kv1
                sa0 += wt * a0
                sa1 += wt * a1
            q0 += h6 * sv0
            q1 += h6 * sv1
            v0 += h6 * sa0
            v1 += h6 * sa1
            state[0] = q0
            state[1] = q1
            state[2] = v0
            state[3] = v1
            _integrate_reference(state, dqd, dqd_end, h, n)
            _integrate_error(kind, state, e1, tau, tau_limit, h, n)
            rho = state[8] + h * rho_dot
            state[8] = rho
            if record:
                _log_torque(log[steps], tau, tau_limit, n)
            if tracing:
                trace[steps, 2] = tau0
                trace[steps, 3] = tau1
            steps += 1
            if not (
                abs(v0) <= DIVERGENCE_SPEED
                and abs(v1) <= DIVERGENCE_SPEED
                and abs(q0) < np.inf
                and abs(q1) < np.inf
                and abs(rho) < np.inf
            ):
                return steps, True
        for i in range(n):
            prev[i] = cmd[i]
    return steps, False


# --- generic path ------------------------------------------------------------------------------


@njit(cache=True, error_model="numpy", fastmath=_FAST, inline="always")
def _stage_terms(xs: Array, n: int, f_terms: Array, rows: Array, acc: Array) -> None:
    """acc += F at the stage state xs = [q, q̇], from the step's cached series (or libm)."""
    cap = rows.shape[0]
    for r in range(f_terms.shape[0]):
        src = int(f_terms[r, 4])
        x = xs[src] if int(f_terms[r, 3]) == SOURCE_Q else xs[n + src]
        phi = f_terms[r, 2] * x
        d = phi - rows[r, 0] if r < cap else np.inf
        val = _poly7(rows, r, d) if abs(d) <= ROTATE_MAX else f_terms[r, 1] * math.cos(phi)
        acc[int(f_terms[r, 0])] += val


@njit(cache=True, error_model="numpy", fastmath=_FAST, _nrt=False)  # type: ignore[call-overload]
def _run_generic(
    state: Array,
    commands: Array,
    hold: int,
    k0: int,
    kind: int,
    gains: Array,
    model: Model,
    dt: float,
    key: np.uint64,
    work: Array,
    log: Array,
    trace: Array,
    ramp: bool,
) -> tuple[int, bool]:
    """`_run` for any n: loops over links and a Cholesky solve."""
    n = state.shape[0] // 4
    weights, gcoef, lengths, f_terms, dist, tau_limit = model
    cap = int(work[1])
    tb, fb, lb, db, rb, _, o = _offsets(n, cap)
    tau = work[tb : tb + n]
    prev = work[fb : fb + n]
    dqd = work[fb + n : fb + 2 * n]
    dqd_end = work[fb + 2 * n : fb + 3 * n]
    phi0 = work[lb : lb + n]
    cth = work[lb + n : lb + 2 * n]
    sth = work[lb + 2 * n : lb + 3 * n]
    dslots = work[db : db + 3 * n].reshape((3, n))
    rows = work[rb : rb + _ROW * cap].reshape((cap, _ROW))
    rows_m = rows[: min(f_terms.shape[0], cap)]
    mass = work[o : o + n * n].reshape((n, n))
    o += n * n
    low = work[o : o + n * n].reshape((n, n))
    o += n * n
    bias = work[o : o + n]
    th = work[o + n : o + 2 * n]
    om = work[o + 2 * n : o + 3 * n]
    e1 = work[o + 3 * n : o + 4 * n]
    y2 = work[o + 4 * n : o + 5 * n]
    rhs = work[o + 5 * n : o + 6 * n]
    acc = work[o + 6 * n : o + 7 * n]
    xs = work[o + 7 * n : o + 9 * n]
    kv = work[o + 9 * n : o + 10 * n]
    sv = work[o + 10 * n : o + 11 * n]
    sa = work[o + 11 * n : o + 12 * n]
    sc = work[o + 12 * n : o + 13 * n]
    ss = work[o + 13 * n : o + 14 * n]
    ext = work[o + 14 * n : o + 17 * n].reshape((3, n))
    rot = work[o + 17 * n : o + 21 * n].reshape((4, n))
    _rotations(dist, dt, rot)
    h = dt
    record = log.shape[0] > 0
    tracing = trace.shape[0] > 0
    steps = 0
    for ci in range(commands.shape[0]):
        cmd = commands[ci]
        for j in range(hold):
            k = k0 + steps
            t = k * dt
            _reference(ramp, cmd, prev, j, hold, dqd, dqd_end)
            if record:
                _log_row(log[steps], t, state, dqd, n, lengths)
            if tracing:
                for i in range(n):
                    trace[steps, i] = state[i] - state[2 * n + i]
            anchor = (k & _ANCHOR_MASK) == 0
            q = state[0:n]
            v = state[n : 2 * n]
            absolute_angles(q, v, th, om)
            for a in range(n):
                if anchor:
                    c = math.cos(th[a])
                    s = math.sin(th[a])
                else:
                    c, s = _turn(th[a], phi0[a], cth[a], sth[a])
                phi0[a] = th[a]
                cth[a] = c
                sth[a] = s
            _base_rows(state, n, anchor, f_terms, rows_m)
            _base_dist(t, anchor, dist, dslots)
            _disturbance(key, k, dist, rot, dslots, ext)
            mass_and_bias_cs(cth, sth, om, weights, gcoef, mass, bias)
            rho_dot = control(kind, gains, state, dqd, mass, tau_limit, tau, e1, y2)
            for i in range(n):
                rhs[i] = tau[i] - bias[i]
                xs[i] = q[i]
                xs[n + i] = v[i]
            cholesky_solve(mass, rhs, low, acc)
            _stage_terms(xs, n, f_terms, rows_m, acc)
            for i in range(n):
                acc[i] += ext[0, i]
                sv[i] = v[i]
                sa[i] = acc[i]
                kv[i] = v[i]
            for st in range(3):
                fr = 0.5 * h if st < 2 else h
                for i in range(n):
                    xs[i] = q[i] + fr * kv[i]
                    xs[n + i] = v[i] + fr * acc[i]
                absolute_angles(xs[0:n], xs[n : 2 * n], th, om)
                for a in range(n):
                    sc[a], ss[a] = _turn(th[a], phi0[a], cth[a], sth[a])
                mass_and_bias_cs(sc, ss, om, weights, gcoef, mass, bias)
                for i in range(n):
                    rhs[i] = tau[i] - bias[i]
                cholesky_solve(mass, rhs, low, acc)
                _stage_terms(xs, n, f_terms, rows_m, acc)
                e = 1 if st < 2 else 2
                wt = 2.0 if st < 2 else 1.0
                for i in range(n):
                    acc[i] += ext[e, i]
                    sv[i] += wt * xs[n + i]
                    sa[i] += wt * acc[i]
                    kv[i] = xs[n + i]
            for i in range(n):
                state[i] += h / 6.0 * sv[i]
                state[n + i] += h / 6.0 * sa[i]
            _integrate_reference(state, dqd, dqd_end, h, n)
            _integrate_error(kind, state, e1, tau, tau_limit, h, n)
            state[4 * n] += h * rho_dot
            if record:
                _log_torque(log[steps], tau, tau_limit, n)
            if tracing:
                for i in range(n):
                    trace[steps, n + i] = tau[i]
            steps += 1
            if _diverged(state, n):
                return steps, True
        for i in range(n):
            prev[i] = cmd[i]
    return steps, False


@njit(cache=True)
def _run(
    state: Array,
    commands: Array,
    hold: int,
    k0: int,
    kind: int,
    gains: Array,
    model: Model,
    dt: float,
    key: np.uint64,
    work: Array,
    log: Array,
    trace: Array,
    ramp: bool,
) -> tuple[int, bool]:
    """Run ``hold`` steps of each command row of ``commands`` from step index ``k0``.

    The reference q̇_d follows each command through `_reference` (``ramp`` or hold), starting
    from the previous command kept in ``work``. Row s of ``log`` (when it has rows) gets the
    logged quantities of the s-th step, row s of ``trace`` (when it has rows) gets e1 at that
    step's start and the torque applied during it (2n columns). Returns (steps run, diverged);
    a diverging step is run and counted, and ends the call.
    """
    if commands.shape[1] == 2:
        return _run_two(
            state, commands, hold, k0, kind, gains, model, dt, key, work, log, trace, ramp
        )
    return _run_generic(
        state, commands, hold, k0, kind, gains, model, dt, key, work, log, trace, ramp
    )


@njit(cache=True)
def advance(
    state: Array,
    dqd: Array,
    k0: int,
    n_steps: int,
    kind: int,
    gains: Array,
    model: Model,
    dt: float,
    key: np.uint64,
    work: Array,
    log: Array,
    ramp: bool,
) -> int:
    """Run ``n_steps`` controller steps from step index ``k0`` towards the command ``dqd``.

    With ``ramp`` q̇_d moves linearly from the previous command to ``dqd`` over the
    ``n_steps``; otherwise it is held at ``dqd``. Returns the number of steps completed:
    ``n_steps`` unless the loop diverged. When ``log`` has rows, row s receives the
    `trajectory_columns` at the start of step s, with the τ applied during that step. ``key`` is
    `stream_key`'s value as an ``np.uint64`` (a Python int above 2⁶³ makes every call go through
    numba's slow type resolution).
    """
    n = dqd.shape[0]
    done, diverged = _run(
        state, dqd.reshape((1, n)), n_steps, k0, kind, gains, model, dt, key, work, log,
        np.empty((0, 2 * n)), ramp,
    )  # fmt: skip
    return done - 1 if diverged else n_steps


@njit(cache=True, parallel=True)
def simulate_batch(
    kind: int,
    gains: Array,
    q0: Array,
    offset: Array,
    commands: Array,
    steps_per_command: int,
    model: Model,
    dt: float,
    seeds: Array,
    trace: Array,
    ramp: bool,
) -> NDArray[np.int64]:
    """Closed-loop runs of every gain candidate on every reference scenario, in parallel.

    gains (K, p); per scenario s: q_d(0) = q0[s], q(0) = q0[s] + offset[s], q̇(0) = q̇_d(0) = 0,
    and q̇_d follows commands[s] (C, n) through the reference generator (``ramp`` or hold), each
    command for ``steps_per_command`` periods. Fills trace[K, S, C·steps_per_command, 2n] with
    e1 = q − q_d at the start of every step and the torque applied during it (NaN after a
    divergence) and returns the number of steps each run completed, shape (K, S).
    """
    n_cand = gains.shape[0]
    n_scen = q0.shape[0]
    n = q0.shape[1]
    total = commands.shape[1] * steps_per_command
    done = np.empty((n_cand, n_scen), dtype=np.int64)
    for idx in prange(n_cand * n_scen):
        c = idx // n_scen
        s = idx % n_scen
        work = make_work(n)
        state = np.zeros(4 * n + 1)
        for i in range(n):
            state[i] = q0[s, i] + offset[s, i]
            state[2 * n + i] = q0[s, i]
        key = stream_key(int(seeds[s]))
        first = 0 * n  # a run-time zero: a literal 0 would make numba compile `_run` again
        completed, _ = _run(
            state, commands[s], steps_per_command, first, kind, gains[c], model, dt, key, work,
            np.empty((0, 4 + 6 * n)), trace[c, s], ramp,
        )  # fmt: skip
        for kk in range(completed, total):
            for i in range(2 * n):
                trace[c, s, kk, i] = np.nan
        done[c, s] = completed
    return done


class Simulator:
    """One closed loop (plant + controller) with its state, for stages and environments.

    >>> sim = Simulator(plant, "subsystem_adaptive", gains, q0=[0.0, 0.0], seed=0)
    >>> sim.advance([0.1, -0.2], 30)   # one 30 ms environment step
    """

    def __init__(
        self,
        plant: Plant,
        controller: str,
        gains: Array,
        q0: Array | list[float],
        seed: int = 0,
        qd0: Array | list[float] | None = None,
        reference: str = "ramp",
    ) -> None:
        if controller not in KINDS:
            raise ValueError(f"controller={controller!r} is unknown; choose one of {list(KINDS)}.")
        if reference not in REFERENCES:
            raise ValueError(f"reference={reference!r} is unknown; choose one of {REFERENCES}.")
        self.plant = plant
        self.reference = reference
        self.ramp = reference == "ramp"
        self.kind = KINDS[controller]
        self.gains = np.ascontiguousarray(gains, dtype=np.float64)
        self.n = plant.arm.n
        self._model = plant.packed()
        self._work = make_work(self.n)
        self._no_log = np.zeros((0, log_width(self.n)))
        self.state = np.zeros(4 * self.n + 1)
        self.reset(q0, seed=seed, qd0=qd0)

    def reset(
        self, q0: Array | list[float], seed: int = 0, qd0: Array | list[float] | None = None
    ) -> None:
        """Put the arm at rest at ``q0`` with q_d(0) = ``qd0`` (default q0), q̇_d = 0, ρ̂ = 0,
        t = 0."""
        n = self.n
        self.state[:] = 0.0
        self.state[:n] = q0
        self.state[2 * n : 3 * n] = q0 if qd0 is None else qd0
        self.step_index = 0
        self.seed = int(seed)
        # An np.uint64, not the Python int numba returns: a Python int above 2⁶³ sends every
        # `advance` call through numba's slow type resolution (≈ 370 µs instead of ≈ 2 µs).
        self._key = np.uint64(stream_key(self.seed))
        # The last τ and the reference generator's state (the blocks before the link slots).
        tau, _, links, *_ = _offsets(n, int(self._work[1]))
        self._work[tau:links] = 0.0
        clear_cache(self._work)
        self.diverged = False

    def advance(self, dqd: Array | list[float], n_steps: int, log: bool = False) -> Array | None:
        """Command q̇_d = ``dqd`` for ``n_steps`` controller periods (ramped to it from the last
        command, or held; see `advance`); returns the logged rows when ``log``.

        After a divergence the state is left as it was and `diverged` is set; further calls do
        nothing (a diverged episode is an outcome, not an exception).
        """
        rows = np.zeros((n_steps, log_width(self.n))) if log else self._no_log
        if self.diverged:
            return rows[:0] if log else None
        cmd = np.ascontiguousarray(dqd, dtype=np.float64)
        done = advance(
            self.state,
            cmd,
            self.step_index,
            n_steps,
            self.kind,
            self.gains,
            self._model,
            self.plant.dt,
            self._key,
            self._work,
            rows,
            self.ramp,
        )
        self.step_index += done
        if done < n_steps:
            self.diverged = True
            self.step_index += 1
            return rows[: done + 1] if log else None
        return rows if log else None

    @property
    def q(self) -> Array:
        return self.state[: self.n]

    @property
    def dq(self) -> Array:
        return self.state[self.n : 2 * self.n]

    @property
    def q_d(self) -> Array:
        return self.state[2 * self.n : 3 * self.n]

    @property
    def rho_hat(self) -> float:
        return float(self.state[4 * self.n])

    @property
    def tau(self) -> Array:
        """Torque applied during the last step."""
        return self._work[2 : 2 + self.n]

    @property
    def time(self) -> float:
        return self.step_index * self.plant.dt

    def tip(self) -> tuple[float, float]:
        x, y = tip_position(self.q, self._model[2])
        return float(x), float(y)
