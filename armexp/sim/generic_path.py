"""The closed loop's step loop for any number of links: loops over the links and a Cholesky
solve of M(q) q̈ = τ − C q̇ − G at each RK4 stage, with the angle cache
(`armexp.sim.angle_cache`) for every cosine and sine."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from armexp.sim.angle_cache import ANCHOR_MASK, ROTATE_MAX, poly7, store_row, turn
from armexp.sim.controllers import control
from armexp.sim.disturbance import base_dist, disturbance, rotations
from armexp.sim.dynamics import absolute_angles, cholesky_solve, mass_and_bias_cs
from armexp.sim.model import SOURCE_Q, Array
from armexp.sim.step import has_diverged, integrate_error, integrate_reference, reference_velocity
from armexp.sim.trajectory import log_row, log_torque
from armexp.sim.work import FASTMATH, ROW, Model, work_offsets


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
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
            c, s = turn(phi, rows[r, 0], rows[r, 1], rows[r, 2])
        store_row(rows, r, phi, c, s, f_terms[r, 1])


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def _stage_terms(xs: Array, n: int, f_terms: Array, rows: Array, acc: Array) -> None:
    """acc += F at the stage state xs = [q, q̇], from the step's cached series (or libm)."""
    cap = rows.shape[0]
    for r in range(f_terms.shape[0]):
        src = int(f_terms[r, 4])
        x = xs[src] if int(f_terms[r, 3]) == SOURCE_Q else xs[n + src]
        phi = f_terms[r, 2] * x
        d = phi - rows[r, 0] if r < cap else np.inf
        val = poly7(rows, r, d) if abs(d) <= ROTATE_MAX else f_terms[r, 1] * math.cos(phi)
        acc[int(f_terms[r, 0])] += val


# ``_nrt=False``: the loop allocates nothing, and without it every array view handed to an
# inlined helper costs an atomic reference-count pair per step (about 220 instead of 120 ns
# per two-link step).
@njit(cache=True, error_model="numpy", fastmath=FASTMATH, _nrt=False)  # type: ignore[call-overload]
def run_generic(
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
    """`armexp.sim.simulator.run_commands` for any n: loops over the links and a Cholesky
    solve."""
    n = state.shape[0] // 4
    weights, gcoef, lengths, f_terms, dist, tau_limit = model
    cap = int(work[1])
    tb, fb, lb, db, rb, _, o = work_offsets(n, cap)
    tau = work[tb : tb + n]
    prev = work[fb : fb + n]
    dqd = work[fb + n : fb + 2 * n]
    dqd_end = work[fb + 2 * n : fb + 3 * n]
    phi0 = work[lb : lb + n]
    cth = work[lb + n : lb + 2 * n]
    sth = work[lb + 2 * n : lb + 3 * n]
    dslots = work[db : db + 3 * n].reshape((3, n))
    rows = work[rb : rb + ROW * cap].reshape((cap, ROW))
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
    ddqd = work[o + 21 * n : o + 22 * n]
    rotations(dist, dt, rot)
    h = dt
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
                for i in range(n):
                    trace[steps, i] = state[i] - state[2 * n + i]
                if trace_rho:
                    trace[steps, 2 * n] = state[4 * n]
            anchor = (k & ANCHOR_MASK) == 0
            q = state[0:n]
            v = state[n : 2 * n]
            absolute_angles(q, v, th, om)
            for a in range(n):
                if anchor:
                    c = math.cos(th[a])
                    s = math.sin(th[a])
                else:
                    c, s = turn(th[a], phi0[a], cth[a], sth[a])
                phi0[a] = th[a]
                cth[a] = c
                sth[a] = s
            _base_rows(state, n, anchor, f_terms, rows_m)
            base_dist(t, anchor, dist, dslots)
            disturbance(key, k, dist, rot, dslots, ext)
            mass_and_bias_cs(cth, sth, om, weights, gcoef, mass, bias)
            for i in range(n):
                ddqd[i] = (dqd_end[i] - dqd[i]) * inv_h
            rho_dot = control(kind, gains, state, dqd, ddqd, mass, tau_limit, tau, e1, y2)
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
                    sc[a], ss[a] = turn(th[a], phi0[a], cth[a], sth[a])
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
            integrate_reference(state, dqd, dqd_end, h, n)
            integrate_error(kind, state, e1, tau, tau_limit, h, n)
            state[4 * n] += h * rho_dot
            if record:
                log_torque(log[steps], tau, tau_limit, n)
            if tracing:
                for i in range(n):
                    trace[steps, n + i] = tau[i]
            steps += 1
            if has_diverged(state, n):
                return steps, True
        for i in range(n):
            prev[i] = cmd[i]
    return steps, False
