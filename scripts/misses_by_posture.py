"""Which held-out targets an evaluated policy of the 2-link paper arm missed, by the elbow angle
their posture needs, and whether its stochastic policy reaches the missed ones below the base.

    python scripts/misses_by_posture.py <eval run id> [...] [--store sqlite:///runs/mlflow.db]
    python scripts/misses_by_posture.py <eval run id> --stochastic 10

For each random target of the evaluations (the adaptive law's episodes; every controller reaches
the same targets): the posture with the elbow on the start's side (q2 > 0) if it is within the
joint limits, else the other one's q2; then the share reached per band of q2. ``--stochastic K``
runs the train run's final policy K times with SAC's own sampling on each below-base target its
deterministic policy missed (docs/plain_agent.md, "Which postures the misses need").
"""

from __future__ import annotations

import argparse
import math
from functools import cache

import mlflow
import pandas as pd
from mlflow.tracking import MlflowClient
from omegaconf import OmegaConf

from armexp.config import ConfigError, compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachSettings
from armexp.tracking.run_ids import resolve

BANDS = [-5 * math.pi / 6 - 1e-9, -2.2, -2.0, -1.8, -1.5, -1.0, 0.0]


@cache
def paper_settings() -> ReachSettings:
    """The default environment's settings: the paper's arm, its limits and bounds, Table I."""
    return settings_from_config(compose_config([]))


def posture_needed(x: float, y: float) -> tuple[bool, float, float]:
    """(whether a posture with q2 > 0 is within the limits, the q1 and q2 of the posture used):
    that posture if it is within them, else the other one (NaN where neither is)."""
    settings = paper_settings()
    l1, l2 = settings.plant.arm.lengths_array
    lower, upper = settings.joint_lower, settings.joint_upper
    c2 = max(-1.0, min(1.0, (x * x + y * y - l1 * l1 - l2 * l2) / (2 * l1 * l2)))
    feasible = []
    for sign in (1.0, -1.0):
        q2 = sign * math.acos(c2)
        q1 = math.atan2(y, x) - math.atan2(l2 * math.sin(q2), l1 + l2 * math.cos(q2))
        if lower[0] <= q1 <= upper[0] and lower[1] <= q2 <= upper[1]:
            feasible.append((q1, q2))
    up = [p for p in feasible if p[1] > 0]
    q1, q2 = (up or feasible or [(math.nan, math.nan)])[0]
    return bool(up), q1, q2


def elbow_needed(x: float, y: float) -> tuple[bool, float]:
    """(whether a posture with q2 > 0 is within the limits, the q2 of the posture used)."""
    start_side, _, q2 = posture_needed(x, y)
    return start_side, q2


def full_id(prefix: str) -> str:
    """The id of the one run whose id starts with ``prefix`` (armexp's own resolver, its sentence
    on exit where there is not exactly one)."""
    try:
        return resolve(MlflowClient(), prefix, "run id", mlflow.get_tracking_uri())
    except ConfigError as refused:
        raise SystemExit(str(refused)) from None


def episodes(client: MlflowClient, run_id: str) -> pd.DataFrame:
    frame = pd.read_csv(client.download_artifacts(run_id, "episodes.csv"))
    mine = frame[(frame.controller == "adaptive") & frame.task.str.startswith("random")].copy()
    needed = [elbow_needed(x, y) for x, y in zip(mine.target_x, mine.target_y, strict=True)]
    mine["start_side"] = [n[0] for n in needed]
    mine["q2"] = [n[1] for n in needed]
    return mine


def stochastic_reaches(client: MlflowClient, run_id: str, frame: pd.DataFrame, k: int) -> None:
    from stable_baselines3 import SAC

    from armexp.agents.rollout import rollout
    from armexp.envs.reach import ReachEnv

    train_id = client.get_run(run_id).data.params["eval.train_run"]
    cfg = OmegaConf.load(client.download_artifacts(train_id, "config.yaml"))
    env = ReachEnv(settings_from_config(cfg))  # type: ignore[arg-type]
    model = SAC.load(client.download_artifacts(train_id, "model/model.zip"), device="cpu")
    missed = frame[(frame.target_y < 0) & ~frame.success.astype(bool)]
    reached = 0
    for x, y in zip(missed.target_x, missed.target_y, strict=True):
        runs = [
            rollout(env, model, {"target": (x, y)}, seed=s, deterministic=False) for s in range(k)
        ]
        reached += sum(e.reason == "reached" for e in runs)
    print(f"{run_id[:8]}: the stochastic policy reached {reached} of {k * len(missed)} episodes "
          f"on the {len(missed)} below-base targets its deterministic policy missed")  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("eval_runs", nargs="+")
    parser.add_argument("--store", default="sqlite:///runs/mlflow.db")
    parser.add_argument("--stochastic", type=int, default=0, metavar="K")
    args = parser.parse_args()
    mlflow.set_tracking_uri(args.store)
    client = MlflowClient()
    runs = [full_id(run) for run in args.eval_runs]
    frames = [episodes(client, run) for run in runs]
    every = pd.concat(frames)
    up = every[every.start_side]
    print(f"elbow on the start's side (q2 > 0): {int(up.success.sum())} of {len(up)} reached")
    other = every[~every.start_side]
    bands = pd.cut(other.q2, BANDS)
    table = other.groupby(bands, observed=True).success.agg(["sum", "size"])
    for band, row in table.iterrows():
        print(f"q2 in {band}: {int(row['sum'])} of {int(row['size'])} reached")
    if args.stochastic:
        for run, frame in zip(runs, frames, strict=True):
            stochastic_reaches(client, run, frame, args.stochastic)


if __name__ == "__main__":
    main()
