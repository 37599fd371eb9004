"""Single-environment steps per second of armexp/Reach-v0 beside gymnasium's Reacher-v5.

Run from the repository root (Reacher-v5 needs MuJoCo: ``pip install "gymnasium[mujoco]"``, which
``nox -s bench`` installs)::

    python benchmarks/env_speed.py            # 50,000 steps per measurement, best of 3
    python benchmarks/env_speed.py --quick

Both environments are made with ``gymnasium.make`` (so both carry gymnasium's default wrappers)
and stepped with the same pre-drawn uniform random actions, resetting when an episode ends;
the unwrapped environments are timed too. One of our steps runs 30 controller steps (30 ms at
1 kHz: the adaptive controller and an RK4 step of the uncertain plant each), one of Reacher's
runs 2 MuJoCo steps. Target: Reach-v0 ≥ 1.5× Reacher-v5.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import armexp  # noqa: F401  (registers armexp/Reach-v0)

TARGET = 1.5


def steps_per_second(env: Any, steps: int, repeats: int) -> float:
    rng = np.random.default_rng(0)
    space = env.action_space
    actions = rng.uniform(space.low, space.high, (steps, *space.shape)).astype(space.dtype)
    best = 0.0
    for r in range(repeats):
        env.reset(seed=r)
        start = time.perf_counter()
        for a in actions:
            _, _, terminated, truncated, _ = env.step(a)
            if terminated or truncated:
                env.reset()
        best = max(best, steps / (time.perf_counter() - start))
    return best


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="5,000 steps per measurement")
    args = parser.parse_args()
    steps = 5_000 if args.quick else 50_000
    repeats = 3
    try:
        reacher = gym.make("Reacher-v5")
    except Exception as exc:  # gymnasium without MuJoCo
        print(f"Reacher-v5 is unavailable ({exc}); install gymnasium[mujoco].")
        return 1
    ours = gym.make("armexp/Reach-v0")
    steps_per_second(ours, 2_000, 1)  # compile and warm up
    steps_per_second(reacher, 2_000, 1)
    rows = [
        ("armexp/Reach-v0 (gym.make)", steps_per_second(ours, steps, repeats)),
        ("Reacher-v5 (gym.make)", steps_per_second(reacher, steps, repeats)),
        ("armexp/Reach-v0 (unwrapped)", steps_per_second(ours.unwrapped, steps, repeats)),
        ("Reacher-v5 (unwrapped)", steps_per_second(reacher.unwrapped, steps, repeats)),
    ]
    for name, rate in rows:
        print(f"{name:<30} {rate:>12,.0f} steps/s")
    wrapped = rows[0][1] / rows[1][1]
    bare = rows[2][1] / rows[3][1]
    print(
        f"ratio Reach-v0 / Reacher-v5: {wrapped:.2f}x with wrappers, {bare:.2f}x unwrapped "
        f"(target >= {TARGET}x): {'PASS' if min(wrapped, bare) >= TARGET else 'MISS'}"
    )
    print(f"controller steps/s inside Reach-v0: {rows[2][1] * 30:,.0f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
