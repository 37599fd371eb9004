"""The diagnostic of docs/plain_agent.md ("On the study's seed 1000"): random exploration, and a
saved policy, under two sets of adaptive gains, the same episodes through the real environment."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from omegaconf import OmegaConf

from armexp.agents.callbacks import CHECKPOINT_DIR, MODEL_FILE
from armexp.agents.factory import build_agent
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.paper import GAINS

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "exploration_by_gains.py"


def _script() -> ModuleType:
    spec = importlib.util.spec_from_file_location("exploration_by_gains", SCRIPT)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # where its dataclass looks itself up
    spec.loader.exec_module(module)
    return module


def test_red_noise_actions_are_correlated_and_within_the_box() -> None:
    script = _script()
    red = script.actions("red", np.random.default_rng(0), 1000)
    uniform = script.actions("uniform", np.random.default_rng(0), 1000)
    assert red.shape == uniform.shape == (1000, 2)
    assert np.abs(red).max() <= 1.0 and np.abs(uniform).max() <= 1.0
    lag_one = [np.corrcoef(a[:-1, 0], a[1:, 0])[0, 1] for a in (red, uniform)]
    assert lag_one[0] > 0.9 and abs(lag_one[1]) < 0.1


def test_the_same_actions_end_the_same_way_under_nearby_gains() -> None:
    script = _script()
    paper = GAINS
    stiffer = {**paper, "a0": paper["a0"] * 1.5}
    tally = script.explore(paper, "red", 3)
    tally_stiffer = script.explore(stiffer, "red", 3)
    assert sum(tally.ends.values()) == 3 and tally.ends == tally_stiffer.ends
    assert len(tally.returns) == 3 and tally.steps == len(tally.errors) > 0
    # the adaptive law keeps the joints within a milliradian of the reference either way
    errors, errors_stiffer = np.asarray(tally.errors), np.asarray(tally_stiffer.errors)
    assert 0.0 < errors.max() < 2e-3 and 0.0 < errors_stiffer.max() < 2e-3
    assert not np.array_equal(errors, errors_stiffer)  # the gains did act
    # the returns differ by what the gains change, a small share of them
    assert np.allclose(tally.returns, tally_stiffer.returns, rtol=0.02)


def test_a_still_arm_pays_the_growth_penalty_on_about_half_its_steps() -> None:
    """Held at its start (zero actions), the arm jitters under the disturbance torque: the tip
    error grows on about every other step, each such step paying Table I's growth penalty."""
    script = _script()
    assert not script.actions("still", np.random.default_rng(0), 5).any()
    tally = script.explore(GAINS, "still", 1)
    assert tally.ends == {"time_limit": 1} and tally.steps == 1000
    assert 0.3 < tally.grown / tally.steps < 0.7
    env = script.make_reach(gains=GAINS)
    env.reset(seed=0)
    distance = env.error - env.settings.reach_threshold
    per_step = -np.log10(1.0 + distance)  # the tip stays where it started, to a micrometre
    expected = 1000 * per_step - tally.grown * env.settings.growth_penalty
    assert tally.returns[0] == pytest.approx(expected, rel=1e-3)


def test_a_saved_policy_is_loaded_from_its_run_folder_and_run_under_both_gain_sets(
    tmp_path: Path,
) -> None:
    script = _script()
    overrides = ["controller.gains=paper", "agent=sac_smoke", "agent.net_arch=[16,16]",
                 "env.max_steps=60"]  # fmt: skip
    cfg = compose_config(overrides)
    env = make_vec_env(settings_from_config(cfg, with_tasks=False), 1, "dummy", 0)
    build_agent(cfg.agent, env, 0).save(tmp_path / CHECKPOINT_DIR / MODEL_FILE)
    OmegaConf.save(cfg, tmp_path / "config.yaml")
    loaded_cfg, model = script.load_policy(tmp_path)
    assert loaded_cfg.env.max_steps == 60
    stiffer = {**GAINS, "a0": GAINS["a0"] * 1.5}
    for deterministic in (True, False):
        tally = script.run_policy(loaded_cfg, model, GAINS, 3, deterministic)
        again = script.run_policy(loaded_cfg, model, GAINS, 3, deterministic)
        stiffer_tally = script.run_policy(loaded_cfg, model, stiffer, 3, deterministic)
        # seeded: the same episodes again
        assert sum(tally.ends.values()) == 3 and tally.ends == again.ends
        assert tally.returns == again.returns
        assert tally.ends == stiffer_tally.ends
        errors = np.asarray(tally.errors)
        assert 0.0 < errors.max() < 2e-3
        assert not np.array_equal(errors, np.asarray(stiffer_tally.errors))
