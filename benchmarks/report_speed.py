"""Wall time of `armexp report` over a store of 50 eval runs (target: ≤ 15 s).

Run from the repository root::

    python benchmarks/report_speed.py          # builds runs/bench_report once (a few minutes)
    python benchmarks/report_speed.py --runs 10

The store is written by real, small stages: a short CSO for each tune run the default eval
reads (its controller's and its baselines', as the pipeline tunes them), a 600-step SAC run
with 100-step episodes, then ``armexp eval -m seed=range(N)`` (each eval: tasks (a)–(d) and two
random targets, the adaptive law and the default baselines). The report over all N eval runs is
then timed twice (the second run reuses nothing: it reads the store again and rewrites every
file); the best is printed with the per-run cost.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mlflow.tracking import MlflowClient

from armexp.cli import main as armexp
from armexp.config import compose_config
from armexp.stages.pipeline import tune_steps
from tests.helpers import SMALL_TRAIN, SMALL_TUNE

TARGET_S = 15.0


def eval_count(runs_dir: Path) -> int:
    db = runs_dir / "mlflow.db"
    if not db.exists():
        return 0
    client = MlflowClient(f"sqlite:///{db.resolve()}")
    exp = client.get_experiment_by_name("armexp")
    if exp is None:
        return 0
    runs = client.search_runs(
        [exp.experiment_id],
        "tags.`armexp.stage` = 'eval' and attributes.status = 'FINISHED'",
        max_results=10_000,
    )
    return len(runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50, help="eval runs in the store")
    parser.add_argument("--runs-dir", default="runs/bench_report")
    args = parser.parse_args()
    runs_dir = Path(args.runs_dir)
    where = f"tracking.runs_dir={runs_dir}"
    have = eval_count(runs_dir)
    if have < args.runs:
        print(f"building the store: {args.runs - have} eval runs to add to {have}")
        if have == 0:  # every tune run the default eval reads: its controller's and baselines'
            for controller, criterion in tune_steps(compose_config()).values():
                line = [f"controller={controller}", f"tuner.objective.criterion={criterion}"]
                assert armexp(["tune", *line, *SMALL_TUNE, where]) == 0
            assert armexp(["train", *SMALL_TRAIN, where]) == 0
        seeds = f"range({have},{args.runs})"
        assert armexp(["eval", "-m", f"seed={seeds}", "tasks.n_random=2", where]) == 0
    n = eval_count(runs_dir)
    times = []
    for _ in range(2):
        start = time.perf_counter()
        rc = armexp(["report", where, "report.filter=\"attributes.status = 'FINISHED'\"",
                     f"report.out_dir={runs_dir / 'report'}"])  # fmt: skip
        times.append(time.perf_counter() - start)
        assert rc == 0
    best = min(times)
    print(f"report over {n} eval runs: {best:.2f} s (runs: {', '.join(f'{t:.2f}' for t in times)})"
          f"; {best / n * 1000:.0f} ms per eval run; target <= {TARGET_S:g} s: "
          f"{'PASS' if best <= TARGET_S else 'MISS'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
