"""Speed of the compiled closed loop against the plain-numpy reference (issue targets).

Run from the repository root::

    python benchmarks/sim_speed.py            # full run (a few seconds once compiled)
    python benchmarks/sim_speed.py --quick    # smaller workloads, for a smoke check

It prints, for the paper's two-link arm with the paper's adaptive gains and eq. 40 uncertainty:

* compiled steps/s on one core: one ``Simulator.advance(cmd, N)`` call after warm-up, best of a
  few repeats, numba limited to one thread;
* batched steps/s: ``simulate_batch`` over candidates × scenarios on all cores (cores reported);
* reference steps/s: ``armexp.sim.reference.simulate`` on fewer steps;
* the ratios compiled/reference and batched/reference, and PASS/MISS against the targets
  (≥ 5 million steps/s compiled on one core, ≥ 200× the reference);
* the three-link compiled steps/s, for information;
* the unrolled two-link loop (`armexp.sim.two_link_path`) against the generic n-link loop
  (`armexp.sim.generic_path`) on the same n = 2 workload, one thread, and their ratio: the
  unrolled loop earns its code only at ≥ 1.5× the generic one.

A "step" is one controller period: the controller plus one RK4 step of the plant (1 ms).
The first run compiles the numba code (cached afterwards, `armexp.jit_cache`).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from armexp.sim import reference
from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, gain_vector
from armexp.sim.generic_path import run_generic
from armexp.sim.model import THREE_LINK, TWO_LINK_PAPER, ArmModel, Plant, Uncertainty
from armexp.sim.noise import stream_key
from armexp.sim.simulator import Simulator, simulate_batch
from armexp.sim.trajectory import log_width
from armexp.sim.two_link_path import run_two_link
from armexp.sim.work import make_work

TARGET_STEPS_PER_S = 5e6
TARGET_RATIO = 200.0
HOLD = 30  # controller steps per command (the agent's 30 ms)
FAST_PATH_MIN = 1.5  # the unrolled two-link loop must beat the generic loop by this factor


def _best_of(repeats: int, fn: Callable[[], None]) -> float:
    """Shortest wall time (s) of ``repeats`` calls of fn."""
    best = np.inf
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return float(best)


def compiled_rate(arm: ArmModel, unc: Uncertainty, steps: int, repeats: int) -> float:
    """Steps/s of one long Simulator.advance call on one thread."""
    n = arm.n
    plant = Plant.build(arm, unc)
    gains = gain_vector(ADAPTIVE, PAPER_GAINS, n)
    q0 = np.linspace(0.3, -0.2, n)
    cmd = np.linspace(0.05, -0.2, n)
    sim = Simulator(plant, "subsystem_adaptive", gains, q0=q0 + 0.05, qd0=q0, seed=1)
    sim.advance(cmd, 1000)  # compile (or load the cache) and warm up

    def run() -> None:
        sim.reset(q0 + 0.05, seed=1, qd0=q0)
        sim.advance(cmd, steps)
        if sim.diverged:
            raise RuntimeError("benchmark run diverged")

    return steps / _best_of(repeats, run)


def path_rates(steps: int, repeats: int) -> tuple[float, float]:
    """Steps/s of the unrolled two-link loop and of the generic loop, same n = 2 workload.

    Both run one long command (the paper's two-link arm and adaptive gains, as in
    `compiled_rate`) on the current numba thread count; their repeats alternate so that a
    change of machine load hits both alike.
    """
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    model = plant.packed()
    gains = gain_vector(ADAPTIVE, PAPER_GAINS, 2)
    q0 = np.array([0.3, -0.2])
    commands = np.array([[0.05, -0.2]])
    key = np.uint64(stream_key(1))
    no_log = np.zeros((0, log_width(2)))
    no_trace = np.empty((0, 4))
    finals: dict[Callable[..., tuple[int, bool]], np.ndarray] = {}

    def once(run: Callable[..., tuple[int, bool]], n_steps: int) -> float:
        state = np.zeros(9)
        state[:2] = q0 + 0.05
        state[4:6] = q0
        work = make_work(2)
        t0 = time.perf_counter()
        done, diverged = run(
            state, commands, n_steps, 0, ADAPTIVE, gains, model, plant.dt, key, work, no_log,
            no_trace, True,
        )  # fmt: skip
        elapsed = time.perf_counter() - t0
        if diverged or done != n_steps:
            raise RuntimeError("benchmark run diverged")
        finals[run] = state
        return elapsed

    paths = (run_two_link, run_generic)
    for run in paths:
        once(run, 1000)  # compile (or load the cache) and warm up
    best = dict.fromkeys(paths, np.inf)
    for _ in range(repeats):
        for run in paths:
            best[run] = min(best[run], once(run, steps))
    if np.abs(finals[run_two_link] - finals[run_generic]).max() > 1e-9:
        raise RuntimeError("the two loops disagree")
    return steps / best[run_two_link], steps / best[run_generic]


def batch_rate(candidates: int, scenarios: int, run_steps: int, repeats: int) -> float:
    """Total steps/s of simulate_batch over candidates × scenarios on all numba threads."""
    n = 2
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    rng = np.random.default_rng(0)
    base = gain_vector(ADAPTIVE, PAPER_GAINS, n)
    gains = base * rng.uniform(0.8, 1.2, size=(candidates, base.size))
    q0 = rng.uniform(-0.5, 0.5, size=(scenarios, n))
    offset = rng.uniform(-0.05, 0.05, size=(scenarios, n))
    n_cmd = max(1, run_steps // HOLD)
    bound = np.array([0.1, 0.4])
    commands = rng.uniform(-1.0, 1.0, size=(scenarios, n_cmd, n)) * bound
    seeds = np.arange(scenarios, dtype=np.float64)  # as the tuner's scenarios hold them
    trace = np.empty((candidates, scenarios, n_cmd * HOLD, 2 * n))
    model = plant.packed()

    def run() -> None:
        done = simulate_batch(
            ADAPTIVE, gains, q0, offset, commands, HOLD, model, plant.dt, seeds, trace, True
        )
        if (done < n_cmd * HOLD).any():
            raise RuntimeError("a benchmark candidate diverged")

    run()  # compile (or load the cache)
    return candidates * scenarios * n_cmd * HOLD / _best_of(repeats, run)


def reference_rate(steps: int) -> float:
    """Steps/s of the plain-numpy reference on the same closed loop."""
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    gains = gain_vector(ADAPTIVE, PAPER_GAINS, 2)
    q0 = np.array([0.3, -0.2])
    commands = np.tile([0.05, -0.2], (steps // HOLD, 1))

    def run() -> None:
        reference.simulate(plant, ADAPTIVE, gains, q0 + 0.05, q0, commands, 1, HOLD, True)

    return steps / _best_of(2, run)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--steps", type=int, default=None, help="steps of the single-core run (default 3e6)"
    )
    parser.add_argument(
        "--batch-candidates", type=int, default=None, help="gain candidates (default 32)"
    )
    parser.add_argument("--quick", action="store_true", help="small workloads (smoke check)")
    args = parser.parse_args(argv)

    steps = args.steps or (300_000 if args.quick else 3_000_000)
    candidates = args.batch_candidates or (8 if args.quick else 32)
    scenarios = 4
    run_steps = 1_500 if args.quick else 12_000
    ref_steps = 300 if args.quick else 2_000
    repeats = 2 if args.quick else 3
    cores = numba.get_num_threads()  # NUMBA_NUM_THREADS: nothing has lowered it yet

    print(f"armexp simulator speed  (cpu cores: {os.cpu_count()}, numba {numba.__version__})")
    print("closed loop: paper two-link arm, adaptive controller (paper gains), eq. 40 terms")

    numba.set_num_threads(1)
    two = compiled_rate(TWO_LINK_PAPER, Uncertainty.paper(), steps, repeats)
    three = compiled_rate(THREE_LINK, Uncertainty.off(3), max(steps // 5, 1000), repeats)
    fast, generic = path_rates(steps, repeats)
    numba.set_num_threads(cores)
    batched = batch_rate(candidates, scenarios, run_steps, repeats)
    ref = reference_rate(ref_steps)

    ok_speed = two >= TARGET_STEPS_PER_S
    ok_ratio = two / ref >= TARGET_RATIO
    print(
        f"compiled, one core   : {two:14,.0f} steps/s   ({1e9 / two:.0f} ns/step, 1 advance call)"
    )
    print(
        f"{f'batched, {cores} core(s)':<21}: {batched:14,.0f} steps/s   "
        f"({candidates} candidates x {scenarios} scenarios x {run_steps // HOLD * HOLD} steps)"
    )
    print(f"numpy reference      : {ref:14,.0f} steps/s   ({ref_steps} steps)")
    print(f"compiled / reference : {two / ref:14,.0f} x")
    print(f"batched / reference  : {batched / ref:14,.0f} x")
    print(f"three-link, one core : {three:14,.0f} steps/s   (information)")
    print(f"n = 2 unrolled loop  : {fast:14,.0f} steps/s   (one core; both loops on one workload)")
    print(f"n = 2 generic loop   : {generic:14,.0f} steps/s")
    print(
        f"unrolled / generic   : {fast / generic:14.2f} x   (keep the unrolled loop at >= "
        f"{FAST_PATH_MIN}x: {'KEEP' if fast / generic >= FAST_PATH_MIN else 'DROP'})"
    )
    print(
        f"target >= {TARGET_STEPS_PER_S / 1e6:.0f} M steps/s compiled on one core: "
        f"{'PASS' if ok_speed else 'MISS'}"
    )
    print(
        f"target >= {TARGET_RATIO:.0f}x the reference (compiled, one core): "
        f"{'PASS' if ok_ratio else 'MISS'}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
