"""The diagnostic of docs/plain_agent.md ("On the study's seed 1000"): random exploration, and a
saved policy, under two sets of adaptive gains, the same episodes through the real environment."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np
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
    ends, errors = script.explore(paper, "red", 3)
    ends_stiffer, errors_stiffer = script.explore(stiffer, "red", 3)
    assert sum(ends.values()) == 3 and ends == ends_stiffer
    # the adaptive law keeps the joints within a milliradian of the reference either way
    assert 0.0 < errors.max() < 2e-3 and 0.0 < errors_stiffer.max() < 2e-3
    assert not np.array_equal(errors, errors_stiffer)  # the gains did act


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
        ends, errors = script.run_policy(loaded_cfg, model, GAINS, 3, deterministic)
        again, _ = script.run_policy(loaded_cfg, model, GAINS, 3, deterministic)
        ends_stiffer, errors_stiffer = script.run_policy(
            loaded_cfg, model, stiffer, 3, deterministic
        )
        assert sum(ends.values()) == 3 and ends == again  # seeded: the same episodes again
        assert ends == ends_stiffer
        assert 0.0 < errors.max() < 2e-3 and not np.array_equal(errors, errors_stiffer)
