"""The closed loop's step loop for the two-link arm, unrolled.

The whole RK4 step lives in scalars: the 2×2 solve is closed-form with one division, and the bias
is written as K + A ω₀² + B ω₁² so a stage waits for its velocity only through two multiply-adds.
It computes what `armexp.sim.generic_path.run_generic` computes for n = 2, with the same angle
cache (`armexp.sim.angle_cache`), to rounding.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from armexp.sim.angle_cache import ANCHOR_MASK, ROTATE_MAX, poly7, store_row, turn, turn_by
from armexp.sim.controllers import control
from armexp.sim.disturbance import base_dist, disturbance, rotations
from armexp.sim.model import SOURCE_Q, Array
from armexp.sim.step import (
    DIVERGENCE_SPEED,
    integrate_error,
    integrate_reference,
    reference_velocity,
)
from armexp.sim.trajectory import log_row, log_torque
from armexp.sim.work import FASTMATH, ROW, Model, work_offsets


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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
            c, s = turn(phi, rows[p, 0], rows[p, 1], rows[p, 2])
        amp = plan[p, 7]
        store_row(rows, p, phi, c, s, amp)
        f0 += plan[p, 4] * (amp * c)
        f1 += plan[p, 5] * (amp * c)
    return f0, f1


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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
            val = poly7(rows, p, d)
        else:
            phi = (plan[p, 0] * qs0 + plan[p, 1] * qs1) + (plan[p, 2] * vs0 + plan[p, 3] * vs1)
            val = plan[p, 7] * math.cos(phi)
        f0 += plan[p, 4] * val
        f1 += plan[p, 5] * val
    return f0, f1


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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
    c0, s0 = turn_by(dq0, qs0, bc0, bs0)
    c1, s1 = turn_by(dq0 + dq1, qs0 + qs1, bc1, bs1)
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


# ``_nrt=False``: the loop allocates nothing, and without it every array view handed to an
# inlined helper costs an atomic reference-count pair per step (about 220 instead of 120 ns
# per two-link step).
@njit(cache=True, error_model="numpy", fastmath=FASTMATH, _nrt=False)  # type: ignore[call-overload]
def run_two_link(
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
    """`armexp.sim.simulator.run_commands` for n = 2: the whole RK4 step lives in scalars."""
    n = 2
    weights, gcoef, lengths, f_terms, dist, tau_limit = model
    cap = int(work[1])
    tb, fb, lb, db, rb, pb, sb = work_offsets(n, cap)
    tau = work[tb : tb + n]
    prev = work[fb : fb + n]
    dqd = work[fb + n : fb + 2 * n]
    dqd_end = work[fb + 2 * n : fb + 3 * n]
    links = work[lb : lb + 3 * n].reshape((3, n))
    dslots = work[db : db + 3 * n].reshape((3, n))
    rows = work[rb : rb + ROW * cap].reshape((cap, ROW))
    plan = work[pb : pb + 8 * cap].reshape((cap, 8))
    mass = work[sb : sb + 4].reshape((2, 2))
    e1 = work[sb + 4 : sb + 6]
    y2 = work[sb + 6 : sb + 8]
    ext = work[sb + 8 : sb + 14].reshape((3, 2))
    rot = work[sb + 14 : sb + 22].reshape((4, 2))
    ddqd = work[sb + 22 : sb + 24]
    rotations(dist, dt, rot)
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
    trace_rho = trace.shape[1] > 2 * n
    inv_h = 1.0 / dt
    steps = 0
    for ci in range(commands.shape[0]):
        cmd = commands[ci]
        for j in range(hold):
            k = k0 + steps
            t = k * dt
            reference_velocity(ramp, cmd, prev, j, hold, dqd, dqd_end)
            if record:
                log_row(log[steps], t, state, dqd, n, lengths)
            if tracing:
                trace[steps, 0] = state[0] - state[4]
                trace[steps, 1] = state[1] - state[5]
                if trace_rho:
                    trace[steps, 4] = state[8]
            q0 = state[0]
            q1 = state[1]
            v0 = state[2]
            v1 = state[3]
            # Slots at the step's start: θ₀ = q₀, θ₁ = q₀ + q₁, the F rows, τ_d.
            anchor = (k & ANCHOR_MASK) == 0
            th1 = q0 + q1
            if anchor:
                bc0 = math.cos(q0)
                bs0 = math.sin(q0)
                bc1 = math.cos(th1)
                bs1 = math.sin(th1)
            else:
                bc0, bs0 = turn(q0, links[0, 0], links[1, 0], links[2, 0])
                bc1, bs1 = turn(th1, links[0, 1], links[1, 1], links[2, 1])
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
            base_dist(t, anchor, dist, dslots)
            disturbance(key, k, dist, rot, dslots, ext)
            # M(q) at the step's start, shared by the controller and RK4 stage 1.
            wc = w01 * (bc0 * bc1 + bs0 * bs1)
            mass[0, 0] = (w00 + w11) + 2.0 * wc
            mass[0, 1] = w11 + wc
            mass[1, 0] = w11 + wc
            mass[1, 1] = w11
            ddqd[0] = (dqd_end[0] - dqd[0]) * inv_h
            ddqd[1] = (dqd_end[1] - dqd[1]) * inv_h
            rho_dot = control(kind, gains, state, dqd, ddqd, mass, tau_limit, tau, e1, y2)
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
            integrate_reference(state, dqd, dqd_end, h, n)
            integrate_error(kind, state, e1, tau, tau_limit, h, n)
            rho = state[8] + h * rho_dot
            state[8] = rho
            if record:
                log_torque(log[steps], tau, tau_limit, n)
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
