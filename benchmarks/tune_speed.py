"""Wall time of the paper's CSO budget on the controller objective, against a plain loop.

Run: ``python benchmarks/tune_speed.py`` (``--quick`` for a smaller budget).

Prints, measured in the same run:

* the paper budget (15 nests, 200 iterations ≈ 6000 candidate evaluations, each a closed-loop
  simulation of the default objective's scenarios) through the batched compiled core, all cores,
  with the constraints of docs/design.md §5 on (the default);
* the cost of the constraints: the time spent in the stability check during that run, and the
  same budget with the constraints off (``gain_margin=null``, no effort terms) — unstable
  candidates are not simulated, so the constrained search can be the faster one;
* evaluations per second of that run;
* a plain per-candidate Python loop over the plain-numpy reference simulator, timed on a few
  candidates and extrapolated per evaluation;
* the ratio, and PASS/MISS against the targets (≤ 10 s wall, ≥ 100× the plain loop).
"""

from __future__ import annotations

import argparse
import os
import time

import numba
import numpy as np
from omegaconf import DictConfig

from armexp.config import compose_config
from armexp.sim import reference
from armexp.stages.tune import build_objective, search_space
from armexp.tune import cuckoo_search
from armexp.tune.cuckoo import CuckooResult
from armexp.tune.objective import TuningObjective
from armexp.tune.space import SearchSpace


def plain_loop_seconds_per_eval(obj: TuningObjective, candidates: np.ndarray) -> float:
    """One candidate at a time, every scenario through the numpy reference simulator."""
    sc = obj.scenarios
    start = time.perf_counter()
    for gains in candidates:
        for s in range(sc.q0.shape[0]):
            reference.simulate(
                obj.plant,
                obj.kind,
                gains,
                sc.q0[s] + sc.offset[s],
                sc.q0[s],
                sc.commands[s],
                int(sc.seeds[s]),
                hold=sc.hold_steps,
                ramp=obj.ramp,
            )
    return (time.perf_counter() - start) / len(candidates)


def _search(
    obj: TuningObjective, cfg: DictConfig, space: SearchSpace
) -> tuple[CuckooResult, float]:
    t = cfg.tuner
    start = time.perf_counter()
    res = cuckoo_search(
        space.objective(obj), space.search_lower, space.search_upper, n_nests=int(t.n_nests),
        n_iterations=int(t.n_iterations), pa=float(t.pa), beta=float(t.beta),
        step_scale=float(t.step_scale), seed=0, abandon=str(t.abandon),
    )  # fmt: skip
    return res, time.perf_counter() - start


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="40 iterations instead of 200")
    ap.add_argument("--controller", default="subsystem_adaptive")
    ap.add_argument("--plain-candidates", type=int, default=2)
    args = ap.parse_args()
    iterations = 40 if args.quick else 200
    base = [f"controller={args.controller}", f"tuner.n_iterations={iterations}"]
    cfg = compose_config(base)
    obj = build_objective(cfg)
    space = search_space(cfg)
    obj(space.gains(space.search_lower))  # compile outside the timing

    check_time = 0.0
    check = obj.stable

    def timed_check(candidates: np.ndarray, sigma: np.ndarray | None = None) -> np.ndarray:
        nonlocal check_time
        t0 = time.perf_counter()
        out = check(candidates, sigma)
        check_time += time.perf_counter() - t0
        return out

    obj.stable = timed_check  # type: ignore[method-assign]
    res, wall = _search(obj, cfg, space)
    free = build_objective(
        compose_config(
            [*base, "tuner.objective.gain_margin=null", "tuner.objective.effort_weight=0",
             "tuner.objective.saturation_weight=0"]
        )
    )  # fmt: skip
    res_free, wall_free = _search(free, cfg, space)
    evals_per_s = res.n_evaluations / wall
    sc = obj.scenarios
    steps = res.n_evaluations * sc.q0.shape[0] * sc.n_steps

    rng = np.random.default_rng(0)
    lower, upper = space.search_lower, space.search_upper
    cands = space.gains(rng.uniform(lower, upper, size=(args.plain_candidates, lower.size)))
    plain = plain_loop_seconds_per_eval(obj, cands)
    ratio = plain * evals_per_s

    print(f"machine: {os.cpu_count()} cores, numba threads {numba.get_num_threads()}")
    print(f"objective: {sc.q0.shape[0]} scenarios x {sc.n_steps} steps per evaluation")
    print(
        f"CSO {cfg.tuner.n_nests} nests x {iterations} iterations: {res.n_evaluations} "
        f"evaluations in {wall:.2f} s ({evals_per_s:.0f} evaluations/s, "
        f"{steps / wall / 1e6:.2f} M controller steps/s), best {res.best_f:.4g} "
        f"({cfg.tuner.objective.criterion})"
    )
    print(
        f"plain per-candidate loop (numpy reference): {plain:.3f} s per evaluation "
        f"({1 / plain:.2f} evaluations/s) -> the same budget would take "
        f"{plain * res.n_evaluations / 60:.0f} min"
    )
    print(f"speed-up over the plain loop: {ratio:.0f}x")
    print(
        f"constraints: stability check {check_time:.2f} s of the {wall:.2f} s "
        f"({100 * check_time / wall:.0f} %); {int((~np.isfinite(res.scores)).sum())} of "
        f"{res.n_evaluations} candidates infeasible; without constraints the same budget took "
        f"{wall_free:.2f} s (best {res_free.best_f:.4g}), so they cost "
        f"{wall - wall_free:+.2f} s"
    )
    if not args.quick:
        print(f"target paper budget <= 10 s: {'PASS' if wall <= 10 else 'MISS'} ({wall:.2f} s)")
    print(f"target >= 100x plain loop: {'PASS' if ratio >= 100 else 'MISS'} ({ratio:.0f}x)")


if __name__ == "__main__":
    main()
