"""What random exploration, or a trained policy, meets under two sets of adaptive gains:
episodes of zero actions (the arm held at its start), of uniform random actions and of red noise
(β 2, `pink.ColoredNoiseProcess`, as the `coloured_noise` aid draws), or of a train run's
policy, through the real environment (the paper arm, the five obstacles, Table I's reward), the
same episodes under the paper's gains and under the gains given, with how the episodes ended,
their mean return, the share of steps whose tip error grew (Table I's growth penalty) and the
joint tracking error max|q − q_d| after each action.

    python scripts/exploration_by_gains.py --gains 58.02 3192.6 817.5 3.644e-5 1.0
    python scripts/exploration_by_gains.py --gains 58.02 3199.9 284.3 1e-6 1.0 --policy FOLDER

The gains are the adaptive law's a0 a1 b1 c1 r1 (a tune run's `gains.yaml`). ``--policy`` takes a
folder holding a train run's `config.yaml` and a model (`checkpoint/model.zip` or
`model/model.zip`), as `mlflow artifacts download -r <run id> -d FOLDER` writes them; the policy
acts on the run's own environment (its guard included) and training's target draw, deterministic
and sampled. Used for the study's seeds 1000 and 1001, whose trainings trailed under their tuned
gains while the same seeds learnt under the paper's (docs/plain_agent.md, "On the study's seed
1000").
"""

from __future__ import annotations

import argparse
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from pink import ColoredNoiseProcess

from armexp.agents.callbacks import CHECKPOINT_DIR, MODEL_DIR, MODEL_FILE
from armexp.agents.factory import load_agent
from armexp.envs.factory import make_reach, settings_from_config
from armexp.envs.reach import ReachEnv
from armexp.paper import GAINS as PAPER

#: Reset seeds of the policy's episodes: clear of the evaluation's and the checks' draws.
POLICY_RESET_SEEDS = 50_000


#: The kinds of action sequence: none (the arm held at its start), uniform, red noise.
KINDS = ("still", "uniform", "red")


def actions(kind: str, rng: np.random.Generator, steps: int) -> np.ndarray:
    """One episode's actions (steps, 2) in [-1, 1]: zero (`still`: the reference held, what a
    parked policy commands), uniform, or red noise clipped to the box."""
    if kind == "still":
        return np.zeros((steps, 2))
    if kind == "uniform":
        return rng.uniform(-1.0, 1.0, (steps, 2))
    process = ColoredNoiseProcess(beta=2.0, size=(2, steps), rng=rng)
    return np.clip(np.stack([process.sample() for _ in range(steps)]), -1.0, 1.0)


@dataclass
class Tally:
    """What a set of episodes met: how each ended, its return, how many of its steps grew the
    tip error, and the tracking error after each action (rad)."""

    ends: Counter[str] = field(default_factory=Counter)
    returns: list[float] = field(default_factory=list)
    grown: int = 0
    errors: list[float] = field(default_factory=list)

    @property
    def steps(self) -> int:
        """How many steps the episodes took: one tracking error was kept per step."""
        return len(self.errors)


def explore(gains: dict[str, float], kind: str, episodes: int) -> Tally:
    """``episodes`` episodes of ``kind`` actions under ``gains``. The action sequences depend on
    the episode's index only."""
    env = make_reach(gains=gains)
    tally = Tally()
    for episode in range(episodes):
        sequence = actions(kind, np.random.default_rng(episode), env.settings.max_steps)
        _play(env, episode, _replay(sequence), tally)
    return tally


def _replay(sequence: np.ndarray) -> Callable[[np.ndarray, int], np.ndarray]:
    """The actions of ``sequence`` in order, whatever is observed."""
    return lambda _obs, step: sequence[step]


def _play(
    env: ReachEnv, seed: int, act: Callable[[np.ndarray, int], np.ndarray], tally: Tally
) -> None:
    """One episode from ``env.reset(seed=seed)``, ``act(observation, step)`` choosing each
    action, counted into ``tally``."""
    obs, _ = env.reset(seed=seed)
    info: dict[str, object] = {}
    total = 0.0
    for step in range(env.settings.max_steps):
        before = env.error
        obs, reward, terminated, truncated, info = env.step(act(obs, step).astype(np.float32))
        total += reward
        tally.grown += env.error > before
        tally.errors.append(float(np.abs(env.sim.q - env.sim.q_d).max()))
        if terminated or truncated:
            break
    tally.ends[str(info["reason"])] += 1
    tally.returns.append(total)


def load_policy(folder: Path) -> tuple[DictConfig, Any]:
    """A train run's config and model from a folder of its artifacts (the final model if there
    is one, else the latest checkpoint)."""
    cfg = OmegaConf.load(folder / "config.yaml")
    assert isinstance(cfg, DictConfig)
    saved = (folder / MODEL_DIR / MODEL_FILE, folder / CHECKPOINT_DIR / MODEL_FILE)
    model = next(path for path in saved if path.exists())
    return cfg, load_agent(str(model), None, cfg.agent)


def run_policy(
    cfg: DictConfig, model: Any, gains: dict[str, float], episodes: int, deterministic: bool
) -> Tally:
    """``episodes`` episodes of the policy under ``gains`` on its run's environment (training's
    target draw). Episode ``i`` resets with seed ``POLICY_RESET_SEEDS + i`` and, sampled, draws
    its actions after ``torch.manual_seed(i)``: the same episodes under any gains but for what
    the gains change."""
    env = ReachEnv(settings_from_config(cfg, gains=gains, with_tasks=False))
    tally = Tally()

    def act(obs: np.ndarray, _: int) -> np.ndarray:
        return model.predict(obs, deterministic=deterministic)[0]

    for episode in range(episodes):
        torch.manual_seed(episode)
        _play(env, POLICY_RESET_SEEDS + episode, act, tally)
    return tally


def _print(label: str, name: str, tally: Tally) -> None:
    median, p99 = np.quantile(tally.errors, [0.5, 0.99]) * 1e3
    print(
        f"{label:13s} {name:5s} ends {dict(sorted(tally.ends.items()))} | mean return "
        f"{np.mean(tally.returns):.2f} | error grew on {tally.grown / tally.steps:.3f} of the "
        f"steps | max|q - q_d| median {median:.2f} mrad, 99th percentile {p99:.2f} mrad"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gains", type=float, nargs=5, required=True, metavar="A0 A1 B1 C1 R1")
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--policy", type=Path, help="a folder of a train run's artifacts")
    args = parser.parse_args()
    given = dict(zip(PAPER, args.gains, strict=True))
    both = (("paper", PAPER), ("given", given))
    if args.policy is not None:
        cfg, model = load_policy(args.policy)
        for deterministic in (True, False):
            label = "deterministic" if deterministic else "sampled"
            for name, gains in both:
                _print(label, name, run_policy(cfg, model, gains, args.episodes, deterministic))
        return
    for kind in KINDS:
        for name, gains in both:
            _print(kind, name, explore(gains, kind, args.episodes))


if __name__ == "__main__":
    main()
