"""The target-distance curriculum: the environment draws training targets within a radius of the
starting tip, the aid widens that radius over the budget to the whole workspace, and a
non-privileged preset takes it."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp import aids
from armexp.agents.curriculum import WideningReach
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import tips
from armexp.envs.reach import ReachEnv, ReachSettings
from tests.helpers import plain_train, stage_runs

CURRICULUM = (
    "+agent.aids.curriculum={_target_:armexp.agents.curriculum.TargetCurriculum,"
    "start:0.3,full_at:0.5}"
)


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


def _targets(env: ReachEnv, n: int, seed: int = 3) -> np.ndarray:
    env.reset(seed=seed)
    return np.array([env.reset()[0][:2] for _ in range(n)])


def test_the_environment_draws_targets_within_the_reach_and_the_whole_workspace_without_one(
    settings: ReachSettings,
) -> None:
    env = ReachEnv(settings)
    start = tips(np.asarray(settings.q0, float), env._lengths)
    whole = _targets(env, 200)
    assert np.linalg.norm(whole - start, axis=1).max() > 1.0  # far targets exist
    env.set_target_reach(0.3)
    near = _targets(env, 200)
    assert np.linalg.norm(near - start, axis=1).max() <= 0.3 + 1e-9
    assert len({tuple(t) for t in near}) > 10  # a draw among them, not one target
    env.set_target_reach(None)  # back to the same draws as an environment never narrowed
    assert np.array_equal(_targets(env, 50), _targets(ReachEnv(settings), 50))
    env.set_target_reach(1e-6)  # nothing that close: the nearest target
    d = env.start_distances()
    assert np.allclose(_targets(env, 3), env.workspace.points[int(np.argmin(d))])


def test_the_reach_widens_with_the_budget_to_the_whole_workspace(settings: ReachSettings) -> None:
    venv = DummyVecEnv([lambda: ReachEnv(settings)] * 2)
    spent = [0.0]
    widening = WideningReach(0.3, 0.5, lambda: spent[0])
    widening.model = SimpleNamespace(get_env=lambda: venv)  # type: ignore[assignment]  # all it reads
    widening._on_training_start()
    farthest = float(ReachEnv(settings).start_distances().max())
    assert widening.farthest == pytest.approx(farthest)
    assert widening.reach == pytest.approx(0.3)
    spent[0] = 0.25  # half-way to full_at: half-way from start to the farthest target
    widening._on_step()
    assert widening.reach == pytest.approx(0.3 + (farthest - 0.3) / 2, abs=0.01)
    near = venv.get_attr("_near")
    assert all(n is not None and len(n) < len(ReachEnv(settings).workspace) for n in near)
    spent[0] = 0.5
    widening._on_step()
    assert widening.reach is None
    assert venv.get_attr("_near") == [None, None]


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_the_curriculum(runs_dir: Path) -> None:
    assert aids.CURRICULUM.privileged is False
    assert main(plain_train(runs_dir, CURRICULUM)) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.metrics["final/curriculum_reach"] == 0.0  # the whole workspace by the end
