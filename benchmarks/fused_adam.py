"""Training throughput with Adam's fused kernel (``agent.fused_optimizer``, the default) and with
its per-tensor loop.

Run from the repository root (about 2 × ``--rounds`` × ``--seconds`` plus start-up)::

    python benchmarks/fused_adam.py                  # 3 rounds of 60 s per setting
    python benchmarks/fused_adam.py --seconds 30 --rounds 2

Each round trains ``experiment=quick`` (the paper's gains, one torch thread, seed 0) for
``--seconds`` of wall time once with the loop and once fused, alone on the machine and in turn,
so that both settings see the same machine; it prints each job's environment steps per second
of training (``final/env_steps_per_s``, demonstrations excluded) and the ratio of the medians.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from contention import _job, _rate


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    rates: dict[bool, list[float]] = {False: [], True: []}
    with tempfile.TemporaryDirectory(prefix="armexp-fused-") as tmp:
        for r in range(args.rounds):
            for fused in (False, True):
                runs = Path(tmp) / f"{r}-{fused}"
                job = _job(runs, 0, 1, args.seconds, (f"agent.fused_optimizer={fused}",))
                _, err = job.communicate()
                assert job.returncode == 0, err[-2000:]
                rates[fused].append(_rate(runs))
                print(f"round {r + 1}: fused={fused!s:<5} {rates[fused][-1]:.0f} steps/s",
                      flush=True)  # fmt: skip
    loop, fast = statistics.median(rates[False]), statistics.median(rates[True])
    print(f"median: per-tensor loop {loop:.0f} steps/s, fused {fast:.0f} steps/s "
          f"({fast / loop:.2f}×)")  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
