"""Time to competence: an experiment preset from scratch to a held-out success target.

Run from the repository root (about 7 minutes on a 2-core machine for the default)::

    python benchmarks/time_to_competence.py --minutes 5     # experiment=demo, 5 minutes
    python benchmarks/time_to_competence.py --experiment quick --minutes 20
    python benchmarks/time_to_competence.py agent.gamma=0.995  # train overrides after the options

It runs the real stages against their own MLflow store (``runs/bench``, browse it with
``armexp ui tracking.runs_dir=runs/bench``):

1. ``armexp tune`` (the paper's CSO budget) for the adaptive gains, and ``controller=pid`` for
   the baseline;
2. ``armexp train experiment=<--experiment>`` with ``--minutes`` of training wall time,
   evaluating the deterministic policy on 50 held-out targets every ``--eval-every`` steps
   (their time is left out of the wall-time budget);
3. ``armexp eval`` on the four paper tasks and 100 held-out random targets (a seed apart from
   both training and the in-training checks), for both controllers.

It prints the learning curve (success on the in-training held-out targets against steps and
training wall time) and the final evaluation. Target (``--target``, default 0.95): that share of
the 100 random targets reached with ``paper_five`` obstacles within the training budget, and all
four paper tasks reached.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mlflow.tracking import MlflowClient

from armexp.cli import main as armexp


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="demo", help="experiment preset to train")
    parser.add_argument("--minutes", type=float, default=5.0, help="training wall-time budget")
    parser.add_argument("--runs-dir", default="runs/bench", help="MLflow store folder")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--target", type=float, default=0.95, help="held-out success to reach")
    parser.add_argument("--eval-every", type=int, default=20_000, help="steps between checks")
    parser.add_argument(
        "--eval-only", action="store_true", help="evaluate the store's latest train run again"
    )
    parser.add_argument(
        "overrides",
        nargs="*",
        help="extra Hydra overrides for the train stage, e.g. agent.gamma=0.995",
    )
    args = parser.parse_args()
    where = f"tracking.runs_dir={args.runs_dir}"
    for controller in ("subsystem_adaptive", "pid") if not args.eval_only else ():
        if armexp(["tune", f"controller={controller}", "tune.progress=false", where]) != 0:
            return 1
    if not args.eval_only:
        rc = armexp(["train", f"experiment={args.experiment}", f"agent.max_minutes={args.minutes}",
                     f"train.eval_every={args.eval_every}", f"seed={args.seed}",
                     "train.progress=false", where, *args.overrides])  # fmt: skip
        if rc != 0:
            return rc
    if armexp(["eval", "tasks.n_random=100", where]) != 0:
        return 1

    client = MlflowClient(f"sqlite:///{Path(args.runs_dir).resolve()}/mlflow.db")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None

    def latest(stage: str) -> Any:
        (run,) = client.search_runs(
            [exp.experiment_id],
            f"tags.`armexp.stage` = '{stage}'",
            order_by=["attributes.start_time DESC"],
            max_results=1,
        )
        return run

    train, ev = latest("train"), latest("eval")

    def history(key: str) -> dict[int, float]:
        return {m.step: m.value for m in client.get_metric_history(train.info.run_id, key)}

    success, wall = history("eval/success_rate"), history("eval/wall_s")
    rolling = history("rollout/success_rate_100")
    print(f"\nlearning curve of train run {train.info.run_id} (50 held-out targets):")
    print(f"{'env steps':>10} {'train wall (min)':>17} {'held-out success':>17} "
          f"{'training success (last 100)':>28}")  # fmt: skip
    for step in sorted(success):
        near = max((s for s in rolling if s <= step), default=None)
        train_rate = f"{rolling[near]:.2f}" if near is not None else "-"
        print(f"{step:>10} {wall[step] / 60:>17.1f} {success[step]:>17.2f} {train_rate:>28}")
    m, tm = ev.data.metrics, train.data.metrics
    print(f"\ntraining: {tm['final/env_steps']:.0f} steps, {tm['final/episodes']:.0f} episodes, "
          f"{tm['final/wall_s'] / 60:.1f} min")  # fmt: skip
    ok = True
    for label in ("adaptive", "pid"):
        rate = m[f"{label}.random.success_rate"]
        tasks = {t: m.get(f"{label}.{t}.success", 0.0) for t in "abcd"}
        times = {t: m.get(f"{label}.{t}.target_time", float("nan")) for t in "abcd"}
        shown = ", ".join(
            f"({t}) {times[t]:.1f} s" if tasks[t] else f"({t}) missed" for t in "abcd"
        )
        print(f"eval {label:<8}: {rate:.0%} of 100 held-out targets, collisions "
              f"{m[f'{label}.random.collision_rate']:.0%}; tasks {shown}")  # fmt: skip
        if label == "adaptive":
            ok = rate >= args.target and all(tasks.values())
    print(f"target (>= {args.target:.0%} and all four tasks within {args.minutes:g} min): "
          f"{'PASS' if ok else 'MISS'}")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
