"""The overhead of Ray on one machine: a 16-point ``armexp tune tuner=cso_fast`` sweep through
Hydra's Ray launcher on a local cluster (head + one worker node, one CPU each) against the joblib
launcher with the same two workers, wall time side by side. Ray runs twice: as shipped (a fresh
worker process per point, ``max_calls: 1``, which pays armexp's imports every point) and with
workers reused (``max_calls=0``, as joblib's loky does).

Run (root, from the checkout, with ``armexp[cluster]`` installed):
``python benchmarks/ray_vs_joblib.py [--points 16]``. The cluster runs in a private network
namespace with only loopback (Ray advertises the external interface otherwise, ray #26293); the
script re-runs itself there.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
INSIDE = "ARMEXP_BENCH_NETNS"
WORKERS = 2


def sweep(launcher: list[str], runs: Path, points: int, env: dict[str, str]) -> tuple[float, int]:
    """Wall time of the sweep command and how many tune runs FINISHED."""
    command = [sys.executable, "-m", "armexp", "tune", "-m", f"seed=range(0,{points})",
               "tuner=cso_fast", "tune.progress=false", *launcher,
               f"tracking.runs_dir={runs}"]  # fmt: skip
    start = time.perf_counter()
    res = subprocess.run(command, capture_output=True, text=True, env={**os.environ, **env})
    wall = time.perf_counter() - start
    if res.returncode != 0:
        sys.exit(f"the sweep {' '.join(launcher)} failed:\n{res.stderr[-3000:]}")
    from tests.helpers import stage_runs

    done = [r for r in stage_runs(runs, "tune") if r.info.status == "FINISHED"]
    return wall, len(done)


def measure(points: int) -> None:
    from tests.cluster import ray_cluster

    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        joblib = ["hydra/launcher=joblib", f"hydra.launcher.n_jobs={WORKERS}"]
        wall_joblib, n_joblib = sweep(joblib, work / "joblib", points, {})
        start = time.perf_counter()
        with ray_cluster(work) as address:
            up = time.perf_counter() - start
            ray = ["hydra/launcher=ray", "hydra.launcher.ray.remote.num_cpus=1"]
            at = {"RAY_ADDRESS": address}
            wall_ray, n_ray = sweep(ray, work / "ray", points, at)
            reuse = [*ray, "hydra.launcher.ray.remote.max_calls=0"]
            wall_reuse, n_reuse = sweep(reuse, work / "ray-reuse", points, at)
    print(f"{points}-point `armexp tune tuner=cso_fast` sweep, {WORKERS} workers, "
          f"{os.cpu_count()} cores")  # fmt: skip
    rows = [
        (f"joblib (loky, n_jobs={WORKERS}, workers reused)", wall_joblib, n_joblib),
        ("ray, 2 nodes x 1 CPU, fresh worker per point (max_calls=1, shipped)", wall_ray, n_ray),
        ("ray, 2 nodes x 1 CPU, workers reused (max_calls=0)", wall_reuse, n_reuse),
    ]
    for name, wall, done in rows:
        print(
            f"  {name:<70} {wall:6.1f} s wall, {done} runs FINISHED, "
            f"{wall / points:.2f} s/point, {wall / wall_joblib:.2f}x joblib"
        )
    print(f"  starting the Ray cluster took a further {up:.1f} s (not in the sweeps' times)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=16)
    args = parser.parse_args()
    if os.environ.get(INSIDE):
        measure(args.points)
        return
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, INSIDE: "1", "PYTHONPATH": path}
    script = 'ip link set lo up && exec "$@"'
    command = [sys.executable, __file__, f"--points={args.points}"]
    sys.exit(subprocess.run(["unshare", "--net", "--", "sh", "-c", script, "sh", *command],
                            env=env, cwd=ROOT).returncode)  # fmt: skip


if __name__ == "__main__":
    main()
