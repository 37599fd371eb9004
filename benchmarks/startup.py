"""Start-up: the first ``tune`` and ``train`` of a fresh install against the same commands once
the compiled kernels are cached, and where the difference goes.

Run from the repository root (about 5 minutes on a 2-core machine)::

    python benchmarks/startup.py
    python benchmarks/startup.py --no-train     # tune only

Each command runs as a new process, as a user runs it, against an empty cache folder
(``NUMBA_CACHE_DIR``; inductor's cache sits beside it, `armexp.jit_cache`) — the cold run — and
then again on the folder the cold run filled — the warm run. It prints the machine's pace, the
seconds of each, the kernels numba compiled (``NUMBA_DEBUG_CACHE``: "data saved") in each, and
the import time of each stage's module against a bare interpreter. The reference for the ratios
is the warm run of the same command in the same session.
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
sys.path.insert(0, str(ROOT))

from benchmarks.pace import measure  # noqa: E402

ARMEXP = [sys.executable, "-m", "armexp"]
TUNE = ["tune", "controller=subsystem_adaptive", "tuner=cso_paper", "tune.progress=false"]
#: A sac_demo run just past its first updates: the update's graph compiles at the first one.
TRAIN = ["train", "experiment=demo", "agent.max_env_steps=3000", "agent.max_minutes=null",
         "agent.aids.demonstrations.episodes=50", "train.eval_every=0", "train.progress=false",
         "train.checkpoint_every=100000"]  # fmt: skip


def _timed(cmd: list[str], env: dict[str, str]) -> tuple[float, int]:
    """Wall seconds of ``cmd`` and the numba kernels it compiled and saved."""
    start = time.perf_counter()
    done = subprocess.run(cmd, env=env, capture_output=True, text=True, cwd=ROOT, check=False)
    wall = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed:\n{done.stderr[-2000:]}")
    return wall, done.stdout.count("[cache] data saved") + done.stderr.count("[cache] data saved")


def _import_s(module: str) -> float:
    """Best of three: a new interpreter importing ``module``."""
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", f"import {module}"], check=True, cwd=ROOT)
        best = min(best, time.perf_counter() - start)
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-train", action="store_true", help="measure tune only")
    args = parser.parse_args()
    print(measure().line())
    bare = _import_s("sys")
    for module in ("armexp.cli", "armexp.stages.tune", "armexp.stages.train"):
        print(f"import {module:<22} {_import_s(module) - bare:5.2f} s (over a bare interpreter)")
    commands = [("tune", TUNE)] + ([] if args.no_train else [("train", TRAIN)])
    with tempfile.TemporaryDirectory() as tmp:
        env = {
            **os.environ,
            "NUMBA_CACHE_DIR": str(Path(tmp) / "cache"),
            "NUMBA_DEBUG_CACHE": "1",
            "TORCHINDUCTOR_CACHE_DIR": str(Path(tmp) / "inductor"),
        }
        env.pop("TORCHINDUCTOR_FX_GRAPH_CACHE", None)
        where = f"tracking.runs_dir={Path(tmp) / 'runs'}"
        print(f"\n{'command':<8} {'cold (s)':>9} {'warm (s)':>9} {'cold/warm':>10} "
              f"{'kernels compiled cold':>22} {'warm':>5}")  # fmt: skip
        for name, cmd in commands:
            cold, cold_kernels = _timed([*ARMEXP, *cmd, where], env)
            warm, warm_kernels = _timed([*ARMEXP, *cmd, where], env)
            print(f"{name:<8} {cold:9.1f} {warm:9.1f} {cold / warm:10.2f} {cold_kernels:>22} "
                  f"{warm_kernels:>5}")  # fmt: skip
    print("\nThe warm runs compile nothing when the cache keeps every kernel; the cold run's extra "
          "seconds are numba's (and, for train, inductor's) compilation.")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
