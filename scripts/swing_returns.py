"""What Table I's return makes of a swing to a target: each joint of the 2-link paper arm driven
straight at the posture the target needs, at a share of its velocity bound, through the real
environment (the adaptive law at the paper's gains, the five obstacles, Table I's reward), and the
episode's return discounted at several γ; beside it, the return of keeping the arm still.

    python scripts/swing_returns.py --target -0.02 -0.60
    python scripts/swing_returns.py --target -0.02 -0.60 --speeds 1 0.8 --gammas 0.996 0.998

The swing knows the posture the target needs (the closed-form inverse kinematics of
`misses_by_posture.posture_needed`), as a planner does; no non-privileged agent is given it. It
says how much the swing the agents do not find is worth, and how fast it has to be made to be
worth more than what they do instead (docs/plain_agent.md, "Aimed at task (b)").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from misses_by_posture import posture_needed

from armexp.agents.self_imitation import discounted_returns
from armexp.envs.factory import make_reach

#: Action per radian of posture error: full speed until about 0.2 rad from the posture.
GAIN = 5.0


def swing(target: tuple[float, float], speed: float | None) -> tuple[str, np.ndarray, float]:
    """One episode toward ``target``: the joints driven at the posture it needs at the share
    ``speed`` of their bound (None: every action 0, the arm kept still). (how it ended, the
    rewards, the final tip error in m)."""
    env = make_reach()
    _, q1, q2 = posture_needed(*target)
    if not np.isfinite(q2):
        raise SystemExit(f"--target {target[0]} {target[1]} has no posture within the limits.")
    goal = np.array([q1, q2])
    env.reset(seed=0, options={"target": target})  # the same disturbance draws every run
    rewards = []
    ended = False
    while not ended:
        if speed is None:
            action = np.zeros(2)
        else:
            action = np.clip(GAIN * (goal - np.asarray(env.sim.q)[:2]), -speed, speed)
        _, reward, terminated, truncated, _ = env.step(action.astype(np.float32))
        rewards.append(reward)
        ended = terminated or truncated
    return env.reason, np.asarray(rewards), env.error


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--target", nargs=2, type=float, required=True, metavar=("X", "Y"))
    parser.add_argument("--speeds", nargs="+", type=float, default=[1.0, 0.9, 0.8, 0.7, 0.6])
    parser.add_argument("--gammas", nargs="+", type=float, default=[0.995, 0.996, 0.997, 0.998])
    args = parser.parse_args(argv)
    for s in args.speeds:
        if not 0.0 < s <= 1.0:
            raise SystemExit(f"--speeds {s} is not allowed: a share of the bound in (0, 1].")
    target = (args.target[0], args.target[1])
    print("swing  | ends | steps | summed | " + " | ".join(f"γ {g}" for g in args.gammas))
    for speed in [*args.speeds, None]:
        reason, rewards, error = swing(target, speed)
        name = "still" if speed is None else f"{speed:.2f}"
        values = " | ".join(f"{discounted_returns(rewards, g)[0]:.1f}" for g in args.gammas)
        print(f"{name} | {reason} ({100 * error:.1f} cm) | {len(rewards)} | {rewards.sum():.1f} | "
              f"{values}")  # fmt: skip


if __name__ == "__main__":
    main()
