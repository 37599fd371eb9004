"""Steps to competence: an experiment preset from scratch to a held-out success target, at
several seeds, at the preset's step budget.

Run from the repository root (about 15 minutes on a 2-core machine for the default)::

    python benchmarks/time_to_competence.py                          # experiment=demo, seeds 0 1 2
    python benchmarks/time_to_competence.py --seeds 0 1 2 3 --steps 150000
    python benchmarks/time_to_competence.py --experiment quick --eval-every 40000
    python benchmarks/time_to_competence.py -- agent.gradient_steps=4   # train overrides last

It runs the real stages against their own MLflow store (``runs/bench``, browse it with
``armexp ui tracking.runs_dir=runs/bench``):

1. ``armexp tune`` (the paper's CSO budget) of the adaptive law and of the PID baseline
   (``pid_itae``, tuned on the same criterion);
2. ``armexp train -m seed=…`` (Hydra's joblib launcher, ``--jobs`` at a time), each run checking
   the deterministic policy on 50 held-out targets every ``--eval-every`` steps;
3. ``armexp eval`` of each train run on the four paper tasks and 100 held-out random targets (drawn
   apart from the training's checks), with the adaptive law and ``pid_itae``.

It prints the machine's pace, each seed's learning curve, the IQM over seeds with its 95 %
bootstrap band, the steps at which each seed and the IQM first reach ``--target``, the final
evaluation and the seconds per environment step; ``steps_to_competence.png`` (the curve) and
``.csv`` go to the store's folder. Target: ``--target`` of the 100 targets and all four paper
tasks, with both controllers, at every seed.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import numpy as np
from mlflow.tracking import MlflowClient

from armexp.cli import main as armexp
from armexp.report.stats import iqm_columns_ci
from benchmarks.pace import measure

LABELS = ("adaptive", "pid_itae")


def _first_reach(steps: list[int], rates: list[float], target: float) -> int | None:
    return next((s for s, r in zip(steps, rates, strict=True) if r >= target), None)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--experiment", default="demo", help="experiment preset to train")
    parser.add_argument("--steps", type=int, default=None, help="step budget (the preset's)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--jobs", type=int, default=2, help="train runs at a time")
    parser.add_argument("--runs-dir", default="runs/bench", help="MLflow store folder")
    parser.add_argument("--target", type=float, default=0.95, help="held-out success to reach")
    parser.add_argument("--eval-every", type=int, default=10_000, help="steps between checks")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for train")
    args = parser.parse_args()
    pace = measure()
    print(pace.line())
    where = f"tracking.runs_dir={args.runs_dir}"
    for controller in ("subsystem_adaptive", "pid"):
        if armexp(["tune", f"controller={controller}", "tune.progress=false", where]) != 0:
            return 1
    budget = [] if args.steps is None else [f"agent.max_env_steps={args.steps}"]
    started = time.time() * 1000
    seeds = ",".join(str(s) for s in args.seeds)
    rc = armexp(["train", "-m", f"experiment={args.experiment}", f"seed={seeds}", *budget,
                 f"train.eval_every={args.eval_every}", "train.progress=false",
                 "hydra/launcher=joblib", f"hydra.launcher.n_jobs={args.jobs}", where,
                 *args.overrides])  # fmt: skip
    if rc != 0:
        return rc
    client = MlflowClient(f"sqlite:///{Path(args.runs_dir).resolve()}/mlflow.db")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    trains = client.search_runs(
        [exp.experiment_id],
        f"tags.`armexp.stage` = 'train' and attributes.start_time >= {int(started)}",
        order_by=["params.seed ASC"],
    )
    finals: dict[int, dict[str, float]] = {}
    curves: dict[int, dict[int, float]] = {}
    for run in trains:
        seed = int(run.data.params["seed"])
        ev = ["eval", f"eval.train_run={run.info.run_id}", "tasks.n_random=100", where,
              "eval.baselines=[pid_itae]", "eval.ablation=false",
              "eval.animations=false"]  # fmt: skip
        if armexp(ev) != 0:
            return 1
        (done,) = client.search_runs(
            [exp.experiment_id],
            f"tags.`armexp.stage` = 'eval' and tags.`armexp.train_run` = '{run.info.run_id}'",
            order_by=["attributes.start_time DESC"],
            max_results=1,
        )
        trained = client.get_run(run.info.run_id).data.metrics
        finals[seed] = {**done.data.metrics, **{f"train.{k}": v for k, v in trained.items()}}
        history = client.get_metric_history(run.info.run_id, "eval/success_rate")
        curves[seed] = {m.step: m.value for m in history}
    return _print(args, pace, finals, curves)


def _print(args: Any, pace: Any, finals: dict[int, dict[str, float]],
           curves: dict[int, dict[int, float]]) -> int:  # fmt: skip
    seeds = sorted(curves)
    steps = sorted(set.intersection(*(set(c) for c in curves.values())))
    matrix = np.array([[curves[s][k] for k in steps] for s in seeds])
    point, low, high = iqm_columns_ci(matrix)
    print(f"\nheld-out success while training (50 targets), experiment={args.experiment}:")
    print(f"{'env steps (k)':>14} " + " ".join(f"{k / 1000:>5.0f}" for k in steps))
    for s, row in zip(seeds, matrix, strict=True):
        print(f"{f'seed {s}':>14} " + " ".join(f"{v:>5.2f}" for v in row))
    for name, row in (("IQM", point), ("band low", low), ("band high", high)):
        print(f"{name:>14} " + " ".join(f"{v:>5.2f}" for v in row))
    reach = {s: _first_reach(steps, list(matrix[i]), args.target) for i, s in enumerate(seeds)}
    shown = ", ".join(f"seed {s}: {'-' if r is None else f'{r / 1000:.0f} k'}"
                      for s, r in reach.items())  # fmt: skip
    iqm_reach = _first_reach(steps, list(point), args.target)
    print(f"first check at >= {args.target:.0%}: {shown}; IQM: "
          f"{'-' if iqm_reach is None else f'{iqm_reach / 1000:.0f} k'} steps")  # fmt: skip
    folder = Path(args.runs_dir)
    rows = ["steps," + ",".join(f"seed_{s}" for s in seeds) + ",iqm,band_low,band_high"]
    rows += [f"{k}," + ",".join(f"{v:.4f}" for v in (*matrix[:, j], point[j], low[j], high[j]))
             for j, k in enumerate(steps)]  # fmt: skip
    (folder / "steps_to_competence.csv").write_text("\n".join(rows) + "\n")
    _figure(folder / "steps_to_competence.png", steps, matrix, point, low, high, args.target)
    print(f"\nfinal evaluation (100 held-out targets, paper tasks), {pace.line()}:")
    ok = True
    for s in seeds:
        m = finals[s]
        n, wall = m["train.final/env_steps"], m["train.final/wall_s"]
        parts = []
        for label in LABELS:
            rate = m[f"{label}.random.success_rate"]
            tasks = "".join(t for t in "abcd" if m.get(f"{label}.{t}.success", 0.0))
            ok &= rate >= args.target and tasks == "abcd"
            parts.append(f"{label} {rate:.0%} tasks {tasks or '-'}")
        print(f"seed {s}: {n:,.0f} steps in {wall / 60:.1f} min ({1e3 * wall / n:.2f} ms per step; "
              f"up to {args.jobs} jobs at a time) | " + " | ".join(parts))  # fmt: skip
    print(f"target (>= {args.target:.0%} and all four tasks, both controllers, every seed): "
          f"{'PASS' if ok else 'MISS'}; curve and table in {folder}")  # fmt: skip
    return 0


def _figure(path: Path, steps: list[int], matrix: Any, point: Any, low: Any, high: Any,
            target: float) -> None:  # fmt: skip
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.array(steps) / 1000
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for row in matrix:
        ax.plot(x, row, color="0.75", lw=1)
    ax.fill_between(x, low, high, alpha=0.3, label="95 % bootstrap band")
    ax.plot(x, point, lw=2, label=f"IQM over {len(matrix)} seeds")
    ax.axhline(target, color="k", ls="--", lw=1, label=f"{target:.0%}")
    ax.set(xlabel="environment steps (k)", ylabel="held-out success (50 targets)", ylim=(0, 1.02))
    ax.legend(loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
