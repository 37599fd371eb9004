"""What random exploration meets under two sets of adaptive gains: episodes of uniform random
actions and of red noise (β 2, `pink.ColoredNoiseProcess`, as the `coloured_noise` aid draws)
through the real environment (the paper arm, the five obstacles, Table I's reward), the same
action sequences under the paper's gains and under the gains given, with how the episodes ended
and the joint tracking error max|q − q_d| after each action.

    python scripts/exploration_by_gains.py --gains 58.02 3192.6 817.5 3.644e-5 1.0

The gains are the adaptive law's a0 a1 b1 c1 r1 (a tune run's `gains.yaml`). Used for the study's
seed 1000, whose training stalled under its tuned gains while the same seed learnt under the
paper's (docs/plain_agent.md, "On the study's seed 1000").
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
from pink import ColoredNoiseProcess

from armexp.envs.factory import make_reach
from armexp.paper import GAINS as PAPER


def actions(kind: str, rng: np.random.Generator, steps: int) -> np.ndarray:
    """One episode's actions (steps, 2) in [-1, 1]: uniform, or red noise clipped to the box."""
    if kind == "uniform":
        return rng.uniform(-1.0, 1.0, (steps, 2))
    process = ColoredNoiseProcess(beta=2.0, size=(2, steps), rng=rng)
    return np.clip(np.stack([process.sample() for _ in range(steps)]), -1.0, 1.0)


def explore(gains: dict[str, float], kind: str, episodes: int) -> tuple[Counter[str], np.ndarray]:
    """How ``episodes`` episodes of ``kind`` actions ended under ``gains``, and the tracking
    error after each action (rad). The action sequences depend on the episode's index only."""
    env = make_reach(gains=gains)
    ends: Counter[str] = Counter()
    errors: list[float] = []
    for episode in range(episodes):
        env.reset(seed=episode)
        sequence = actions(kind, np.random.default_rng(episode), env.settings.max_steps)
        info: dict[str, object] = {}
        for action in sequence:
            _, _, terminated, truncated, info = env.step(action.astype(np.float32))
            errors.append(float(np.abs(env.sim.q - env.sim.q_d).max()))
            if terminated or truncated:
                break
        ends[str(info["reason"])] += 1
    return ends, np.asarray(errors)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gains", type=float, nargs=5, required=True, metavar="A0 A1 B1 C1 R1")
    parser.add_argument("--episodes", type=int, default=200)
    args = parser.parse_args()
    given = dict(zip(PAPER, args.gains, strict=True))
    for kind in ("uniform", "red"):
        for name, gains in (("paper", PAPER), ("given", given)):
            ends, errors = explore(gains, kind, args.episodes)
            median, p99 = np.quantile(errors, [0.5, 0.99]) * 1e3
            print(
                f"{kind:7s} {name:5s} ends {dict(sorted(ends.items()))} | max|q - q_d| "
                f"median {median:.2f} mrad, 99th percentile {p99:.2f} mrad"
            )


if __name__ == "__main__":
    main()
