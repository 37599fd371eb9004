"""The compiled closed loop: controller + RK4 plant at the controller period (docs/design.md §3).

Per controller step k (t_k = k·dt):

1. u ~ U(0,1) for τ_d is drawn for this period (`armexp.sim.noise`).
2. The controller computes τ from the measured state and M(q); τ is held over the step.
3. The plant q̈ = M⁻¹(τ − C q̇ − G) + F + τ_d(t) (eq. 2) advances by classic RK4.
4. q_d integrates q̇_d exactly; q̇_d comes from the reference generator
   (`armexp.sim.step.reference_velocity`: a ramp from the previous command to the new one across
   the command's period, or a hold). ρ̂ (eq. 12) and the PID integral (with anti-windup at the
   torque limit) advance by explicit Euler.

The closed-loop state is one float vector ``[q, q̇, q_d, ∫e1 dt, ρ̂]`` (length 4n + 1).
`advance` runs k steps in one call (one environment step is 30 of them); `simulate_batch` runs
many gain candidates × reference scenarios in parallel for the tuner. The two-link arm runs the
unrolled loop of `armexp.sim.two_link_path`, other n the loop of `armexp.sim.generic_path`;
cosines and sines come from the angle cache of `armexp.sim.angle_cache`.
"""

from __future__ import annotations

from typing import Literal, overload

import numpy as np
from numba import njit, prange
from numpy.typing import NDArray

from armexp.sim.controllers import KINDS
from armexp.sim.dynamics import tip_position
from armexp.sim.generic_path import run_generic
from armexp.sim.model import Array, Plant
from armexp.sim.noise import stream_key
from armexp.sim.step import REFERENCES
from armexp.sim.trajectory import log_width
from armexp.sim.two_link_path import run_two_link
from armexp.sim.work import TAU_START, Model, clear_cache, make_work, work_offsets


@njit(cache=True)
def run_commands(
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

    The reference q̇_d follows each command through `reference_velocity` (``ramp`` or hold), starting
    from the previous command kept in ``work``. Row s of ``log`` (when it has rows) gets the
    logged quantities of the s-th step, row s of ``trace`` (when it has rows) gets e1 at that
    step's start and the torque applied during it (2n columns), and ρ̂ at the step's start when
    it has a column 2n. Returns (steps run, diverged);
    a diverging step is run and counted, and ends the call.
    """
    if commands.shape[1] == 2:
        return run_two_link(
            state, commands, hold, k0, kind, gains, model, dt, key, work, log, trace, ramp
        )
    return run_generic(
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
    done, diverged = run_commands(
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
    command for ``steps_per_command`` periods. Fills trace[K, S, C·steps_per_command, 2n + 1]
    with e1 = q − q_d and ρ̂ at the start of every step and the torque applied during it (columns
    e1, τ, ρ̂; NaN after a divergence) and returns the number of steps each run completed, shape
    (K, S).
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
        # A run-time zero: a literal 0 would make numba compile `run_commands` again.
        first = 0 * n
        completed, _ = run_commands(
            state, commands[s], steps_per_command, first, kind, gains[c], model, dt, key, work,
            np.empty((0, 4 + 6 * n)), trace[c, s], ramp,
        )  # fmt: skip
        for kk in range(completed, total):
            for i in range(trace.shape[3]):
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
        tau, _, links, *_ = work_offsets(n, int(self._work[1]))
        self._work[tau:links] = 0.0
        clear_cache(self._work)
        self.diverged = False

    @overload
    def advance(self, dqd: Array | list[float], n_steps: int, log: Literal[True]) -> Array: ...
    @overload
    def advance(
        self, dqd: Array | list[float], n_steps: int, log: Literal[False] = ...
    ) -> None: ...
    @overload
    def advance(self, dqd: Array | list[float], n_steps: int, log: bool) -> Array | None: ...
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
        self.record_steps(done, n_steps)
        if done < n_steps:
            return rows[: done + 1] if log else None
        return rows if log else None

    def kernel_args(self) -> tuple[Array, Array, Model, Array, int, float, np.uint64, int, bool]:
        """The closed loop as the leading arguments of a compiled kernel that runs it by `advance`
        (such as `armexp.envs.kernel.env_step`): ``(state, work, model, gains, kind, dt, key,
        step_index, ramp)``.

        The arrays are this simulator's own, updated in place by the kernel; pass the number of
        steps `advance` returned there to `record_steps`. Do not call it after a divergence.
        """
        return (
            self.state, self._work, self._model, self.gains, self.kind, self.plant.dt, self._key,
            self.step_index, self.ramp,
        )  # fmt: skip

    def record_steps(self, done: int, n_steps: int) -> None:
        """Account for a run of ``n_steps`` periods of which `advance` completed ``done``.

        The step index moves past the completed steps; a shorter run diverged in its next step,
        which was run too: the index counts it and `diverged` is set.
        """
        self.step_index += done
        if done < n_steps:
            self.diverged = True
            self.step_index += 1

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
        return self._work[TAU_START : TAU_START + self.n]

    @property
    def time(self) -> float:
        return self.step_index * self.plant.dt

    def tip(self) -> tuple[float, float]:
        x, y = tip_position(self.q, self._model[2])
        return float(x), float(y)
