"""The machine's pace, printed beside every benchmark's figures so they can be compared across
machines: one core's float32 matmul rate and a fixed pure-Python loop.

* matmul: a (256 × 128) by (128 × 128) float32 product with torch on one thread (the shape of a
  hidden layer of the SAC presets at batch 256), best of 5 timings of 2000 products, in GFLOP/s;
* loop: ``for i in range(10**7): x += i`` in the interpreter, best of 3, in seconds.

Run alone (``python benchmarks/pace.py``) it prints the one line the other benchmarks print.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

MATMUL_SHAPE = (256, 128, 128)
LOOP_STEPS = 10**7


@dataclass(frozen=True)
class Pace:
    matmul_gflops: float
    loop_s: float

    def line(self) -> str:
        return (
            f"machine pace: one core {self.matmul_gflops:.0f} GFLOP/s (float32 256x128 @ 128x128 "
            f"matmul), a 10^7-step Python loop {self.loop_s:.2f} s"
        )


def _loop() -> float:
    start = time.perf_counter()
    x = 0
    for i in range(LOOP_STEPS):
        x += i
    return time.perf_counter() - start


def _matmul() -> float:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        m, k, n = MATMUL_SHAPE
        a, b = torch.randn(m, k), torch.randn(k, n)
        for _ in range(50):
            a @ b
        best = float("inf")
        for _ in range(5):
            start = time.perf_counter()
            for _ in range(2000):
                a @ b
            best = min(best, time.perf_counter() - start)
        return 2.0 * m * k * n * 2000 / best / 1e9
    finally:
        torch.set_num_threads(threads)


def measure() -> Pace:
    """The pace of this machine now (about 2 s)."""
    return Pace(_matmul(), min(_loop() for _ in range(3)))


if __name__ == "__main__":
    print(measure().line())
