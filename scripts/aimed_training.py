"""A diagnostic, not a preset: `armexp train` with every training target drawn within ``--radius``
metres of one point (task (b) by default), to ask whether the swing there is learned when training
asks for it at every episode rather than at about one in a hundred.

    python scripts/aimed_training.py --radius 0.15 -- experiment=plain \\
        agent=sac_plain_guard_g996 agent.name=sac_plain_guard_g996_aimed_b seed=100 \\
        agent.max_env_steps=300000 train.gains=config controller.gains=paper

It adds the ``curriculum`` aid with its distances measured from ``--centre`` instead of the
starting tip and its radius held at ``--radius`` (patched in this process, so the training
environments are made to step in it: ``agent.vec_env=dummy``), so the run is the preset's in
everything but the targets drawn. Aiming at a task uses where the task lies, which no
non-privileged agent is told: the run is a measurement of the learner, named by its
``agent.name`` (docs/plain_agent.md, "Aimed at task (b)"). The held-out checks and `armexp
eval` draw from the whole workspace as always.
"""

from __future__ import annotations

import argparse
import sys

import numpy as np

from armexp.agents import curriculum
from armexp.cli import main as armexp
from armexp.envs.reach import ReachEnv


def aim(centre: tuple[float, float], radius: float) -> None:
    """From now on in this process, the curriculum aid draws training targets within ``radius``
    of ``centre`` for the whole run."""
    point = np.asarray(centre, dtype=np.float64)

    def distances(env: ReachEnv) -> np.ndarray:
        return np.asarray(np.linalg.norm(env.workspace.points - point, axis=1))

    ReachEnv.start_distances = distances  # type: ignore[method-assign,assignment]
    curriculum.WideningReach.radius = lambda self: radius  # type: ignore[method-assign]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--centre", nargs=2, type=float, default=[-0.02, -0.60])
    parser.add_argument("--radius", type=float, default=0.15)
    parser.add_argument("overrides", nargs="*", help="armexp train's overrides")
    args = parser.parse_args(argv)
    if not args.radius > 0.0:
        raise SystemExit(f"--radius {args.radius} is not allowed: a distance > 0 (m).")
    aim((args.centre[0], args.centre[1]), args.radius)
    aid = (
        "+agent.aids.curriculum={_target_:armexp.agents.curriculum.TargetCurriculum,"
        f"start:{args.radius},full_at:1.0}}"
    )
    return armexp(["train", *args.overrides, aid, "agent.vec_env=dummy"])


if __name__ == "__main__":
    sys.exit(main())
