"""Training throughput alone and beside a second job, per torch thread count.

Run from the repository root (about 4 × ``--seconds`` plus start-up)::

    python benchmarks/contention.py                  # 120 s per measurement
    python benchmarks/contention.py --seconds 60 --threads 2 1

For each thread count it trains ``experiment=quick`` (the fast preset, with the paper's gains so
no tune run is needed) for ``--seconds`` of wall time alone, then two such jobs at once (seeds 0
and 1), as separate processes against their own stores, and prints each job's environment
steps per second of training (``final/env_steps_per_s``: the learning phase, demonstrations
excluded) with the ratio of the paired to the lone figure.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from mlflow.tracking import MlflowClient

ROOT = Path(__file__).resolve().parents[1]


def _job(runs: Path, seed: int, threads: int, seconds: float) -> subprocess.Popen[str]:
    command = [
        sys.executable, "-m", "armexp", "train", "experiment=quick", "controller.gains=paper",
        f"agent.max_minutes={seconds / 60:.4f}", f"train.torch_threads={threads}",
        "train.eval_every=0", "train.progress=false", f"seed={seed}",
        f"tracking.runs_dir={runs}",
    ]  # fmt: skip
    return subprocess.Popen(command, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)  # fmt: skip


def _rate(runs: Path) -> float:
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    (run,) = client.search_runs([exp.experiment_id], "tags.`armexp.stage` = 'train'")
    return float(run.data.metrics["final/env_steps_per_s"])


def _measure(jobs: int, threads: int, seconds: float, tmp: Path) -> list[float]:
    folders = [tmp / f"j{jobs}-t{threads}-{i}" for i in range(jobs)]
    procs = [_job(f, i, threads, seconds) for i, f in enumerate(folders)]
    for p in procs:
        _, err = p.communicate()
        assert p.returncode == 0, err[-2000:]
    return [_rate(f) for f in folders]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=120.0)
    parser.add_argument("--threads", type=int, nargs="+", default=[2, 1])
    args = parser.parse_args()
    print(f"cores: {os.cpu_count()}; {args.seconds:g} s of training per job")
    with tempfile.TemporaryDirectory(prefix="armexp-contention-") as tmp:
        for threads in args.threads:
            alone = _measure(1, threads, args.seconds, Path(tmp))[0]
            pair = _measure(2, threads, args.seconds, Path(tmp))
            shown = ", ".join(f"{r:.0f}" for r in pair)
            print(f"torch threads {threads}: alone {alone:.0f} steps/s; beside a second job "
                  f"{shown} steps/s ({min(pair) / alone:.2f}× to {max(pair) / alone:.2f}× of "
                  "alone)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
