"""The diagnostic of docs/plain_agent.md ("On the study's seed 1000"): random exploration under
two sets of adaptive gains, the same action sequences through the real environment."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

import numpy as np

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
