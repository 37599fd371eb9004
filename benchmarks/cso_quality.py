"""Quality of our cuckoo search against NiaPy's CuckooSearch at the paper's budget.

Run: ``python benchmarks/cso_quality.py`` (needs ``pip install -e ".[bench]"`` for NiaPy;
``--seeds N`` to change the number of seeds, 25 by default; ``--step-scale S`` to override the
Lévy step scale of ours).

Ours (`armexp.tune.cuckoo_search`) runs with the settings of ``tuner=cso_paper`` (read from the
config: 15 nests, 200 iterations, P_a = 0.25, beta = 1.5 and its step scale), once with each
abandonment rule, ``worst`` and ``per_component``, evaluating every batch in one call. NiaPy's
CuckooSearch gets the same nests, iterations and P_a (its Lévy step scale is fixed at 0.01 and
beta at 1.5) and evaluates one candidate at a time. Both see the same test functions (defined once
here, in numpy) on their standard domains, with the same seeds. The evaluations of every run are
counted, not assumed.

Prints one row per function and dimension: the median over the seeds of the best value found by
each, the number of evaluations of each (per run), and whether ours is no worse than NiaPy's
with each rule; then PASS/MISS for the rule ``cso_paper`` uses.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from armexp.config import compose_config
from armexp.tune import cuckoo_search

FloatArray = NDArray[np.float64]
Fn = Callable[[FloatArray], FloatArray]

DIMS = (5, 10)
RULES = ("worst", "per_component")


def sphere(x: FloatArray) -> FloatArray:
    return np.sum(x**2, axis=1)


def rastrigin(x: FloatArray) -> FloatArray:
    return 10.0 * x.shape[1] + np.sum(x**2 - 10.0 * np.cos(2.0 * np.pi * x), axis=1)


def griewank(x: FloatArray) -> FloatArray:
    i = np.sqrt(np.arange(1, x.shape[1] + 1, dtype=np.float64))
    return 1.0 + np.sum(x**2, axis=1) / 4000.0 - np.prod(np.cos(x / i), axis=1)


def ackley(x: FloatArray) -> FloatArray:
    d = x.shape[1]
    a = -20.0 * np.exp(-0.2 * np.sqrt(np.sum(x**2, axis=1) / d))
    return a - np.exp(np.sum(np.cos(2.0 * np.pi * x), axis=1) / d) + 20.0 + np.e


def schwefel(x: FloatArray) -> FloatArray:
    return 418.9828872724339 * x.shape[1] - np.sum(x * np.sin(np.sqrt(np.abs(x))), axis=1)


#: name -> (function, half-width of the standard symmetric domain); all minima are 0.
FUNCTIONS: dict[str, tuple[Fn, float]] = {
    "sphere": (sphere, 5.12),
    "rastrigin": (rastrigin, 5.12),
    "griewank": (griewank, 600.0),
    "ackley": (ackley, 32.768),
    "schwefel": (schwefel, 500.0),
}


def run_ours(
    f: Fn, d: int, half: float, seed: int, tuner: dict[str, float | int], rule: str
) -> tuple[float, int]:
    calls = [0]

    def counted(x: FloatArray) -> FloatArray:
        calls[0] += x.shape[0]
        return f(x)

    res = cuckoo_search(
        counted,
        [-half] * d,
        [half] * d,
        n_nests=int(tuner["n_nests"]),
        n_iterations=int(tuner["n_iterations"]),
        pa=float(tuner["pa"]),
        beta=float(tuner["beta"]),
        step_scale=float(tuner["step_scale"]),
        seed=seed,
        abandon=rule,
    )
    assert calls[0] == res.n_evaluations
    return res.best_f, calls[0]


def run_niapy(
    f: Fn, d: int, half: float, seed: int, tuner: dict[str, float | int]
) -> tuple[float, int]:
    from niapy.algorithms.basic import CuckooSearch
    from niapy.problems import Problem
    from niapy.task import Task

    class Wrapped(Problem):
        def _evaluate(self, x: FloatArray) -> float:
            return float(f(np.asarray(x, dtype=np.float64)[None, :])[0])

    problem = Wrapped(dimension=d, lower=-half, upper=half)
    task = Task(problem=problem, max_iters=int(tuner["n_iterations"]))
    algo = CuckooSearch(population_size=int(tuner["n_nests"]), pa=float(tuner["pa"]), seed=seed)
    _, best = algo.run(task)
    return float(best), int(task.evals)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=25, help="seeds per function (default 25)")
    ap.add_argument("--step-scale", type=float, default=None, help="override ours' step scale")
    args = ap.parse_args()
    seeds = range(args.seeds)
    try:
        import niapy
    except ImportError:
        raise SystemExit(
            'NiaPy is not installed; install the bench extra: pip install -e ".[bench]".'
        ) from None
    cfg = compose_config(["tuner=cso_paper"]).tuner
    keys = ("n_nests", "n_iterations", "pa", "beta", "step_scale")
    tuner: dict[str, float | int] = {k: cfg[k] for k in keys}
    if args.step_scale is not None:
        tuner["step_scale"] = args.step_scale
    chosen = str(cfg.abandon)

    print(
        f"ours: tuner=cso_paper, {tuner['n_nests']} nests, {tuner['n_iterations']} iterations, "
        f"P_a {tuner['pa']}, beta {tuner['beta']}, step scale {tuner['step_scale']} "
        f"(cso_paper's rule: {chosen}); reference: NiaPy {niapy.__version__} CuckooSearch, same "
        f"nests, iterations and P_a; median best value over {args.seeds} seeds (minimum 0)"
    )
    header = (
        f"| {'function':<9} | {'dim':>3} | {'ours (worst)':>12} | {'ours (per_component)':>20} "
        f"| {'NiaPy':>10} | {'evaluations (w / pc / NiaPy)':>28} | {'ours <= NiaPy (w / pc)':>22} |"
    )
    print(header)
    print("|" + "|".join("-" * (len(c)) for c in header.split("|")[1:-1]) + "|")
    start = time.perf_counter()
    misses = 0
    for name, (f, half) in FUNCTIONS.items():
        for d in DIMS:
            med: dict[str, float] = {}
            evals: dict[str, set[int]] = {}
            for rule in RULES:
                runs = [run_ours(f, d, half, s, tuner, rule) for s in seeds]
                med[rule] = float(np.median([r[0] for r in runs]))
                evals[rule] = {r[1] for r in runs}
            ref = [run_niapy(f, d, half, s, tuner) for s in seeds]
            med["niapy"] = float(np.median([r[0] for r in ref]))
            evals["niapy"] = {r[1] for r in ref}
            ev = " / ".join("/".join(str(e) for e in sorted(evals[k])) for k in (*RULES, "niapy"))
            ok = " / ".join("yes" if med[r] <= med["niapy"] else "NO" for r in RULES)
            misses += med[chosen] > med["niapy"]
            print(
                f"| {name:<9} | {d:>3} | {med['worst']:>12.4g} | {med['per_component']:>20.4g} "
                f"| {med['niapy']:>10.4g} | {ev:>28} | {ok:>22} |"
            )
    verdict = "PASS" if misses == 0 else f"MISS on {misses} rows"
    print(
        f"cso_paper's rule ({chosen}) no worse than NiaPy on every row: {verdict}; "
        f"wall time {time.perf_counter() - start:.1f} s"
    )


if __name__ == "__main__":
    main()
