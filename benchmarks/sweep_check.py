"""Seconds `armexp <stage> -m …` spends checking every job's config before the first job starts.

Run from the repository root::

    python benchmarks/sweep_check.py                       # the three sweeps below, 200 jobs each
    python benchmarks/sweep_check.py tune -m 'tuner.seed=range(0,200)'

It runs the command in this process up to the point where the sweep would open its MLflow run
(the check is then over), against a throw-away runs folder, and prints the seconds from the
command's start: argument parsing, the check of every job, and Hydra's launcher settings; as a
ratio, against a one-job sweep's check measured in the same run (the reference), with the
machine's pace (`benchmarks.pace`).
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.pace import measure

#: The reference: the same check for a sweep of one job.
ONE_JOB = ["tune", "-m", "tuner.seed=0"]
SWEEPS = [
    ["tune", "-m", "tuner.seed=range(0,200)"],
    ["tune", "-m", "experiment=smoke", "seed=range(0,200)"],
    ["tune", "-m", "controller=subsystem_adaptive,pid", "tuner.seed=range(0,100)"],
]


class _Checked(Exception):
    pass


def check_seconds(args: list[str]) -> float:
    from armexp.cli import main
    from armexp.tracking import sweeps

    def stop(*_: Any, **__: Any) -> Any:
        raise _Checked

    sweeps.open_sweep = stop
    with tempfile.TemporaryDirectory() as folder:
        start = time.perf_counter()
        try:
            code = main([*args, f"tracking.runs_dir={folder}/runs"])
        except _Checked:
            return time.perf_counter() - start
    raise SystemExit(f"{' '.join(args)} stopped before its sweep (exit code {code})")


def main() -> None:
    import armexp.cli  # noqa: F401  (imports are not part of the check)

    print(measure().line(), flush=True)
    reference = check_seconds(ONE_JOB)
    print(f"{reference:6.1f} s  armexp {' '.join(ONE_JOB)}  (reference)", flush=True)
    for args in [sys.argv[1:]] if len(sys.argv) > 1 else SWEEPS:
        seconds = check_seconds(args)
        print(f"{seconds:6.1f} s  {seconds / reference:5.1f}x  armexp {' '.join(args)}", flush=True)


if __name__ == "__main__":
    main()
