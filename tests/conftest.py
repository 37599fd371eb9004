from __future__ import annotations

import os

# Two pytest-xdist workers share a 2-core machine: one torch thread each, here and in the armexp
# processes tests start, so that neither spins threads waiting for a core the other holds.
os.environ.setdefault("OMP_NUM_THREADS", "1")

from collections.abc import Callable
from pathlib import Path

import pytest
from omegaconf import DictConfig

from armexp.cli import main
from armexp.config import compose_config
from tests.helpers import SMALL_TRAIN, SMALL_TUNE, pid_baseline


@pytest.fixture
def runs_dir(tmp_path: Path) -> Path:
    """A private runs/ folder (MLflow store + Hydra folders) for one test."""
    return tmp_path / "runs"


@pytest.fixture
def compose(runs_dir: Path) -> Callable[..., DictConfig]:
    """Compose the real config tree (Hydra compose API) with the store under tmp_path."""

    def _compose(*overrides: str) -> DictConfig:
        return compose_config([*overrides, f"tracking.runs_dir={runs_dir}"])

    return _compose


@pytest.fixture(scope="session")
def store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store written by short real runs: tune (adaptive, PID) → train → eval (runs folder).
    Both tune under the default criterion, and the eval runs the PID baseline of that criterion
    (`tests.helpers.pid_baseline`) beside the policy's controller and its ablation."""
    runs = tmp_path_factory.mktemp("store") / "runs"
    where = f"tracking.runs_dir={runs}"
    assert main(["tune", *SMALL_TUNE, where]) == 0
    assert main(["tune", "controller=pid", *SMALL_TUNE, where]) == 0
    assert main(["train", *SMALL_TRAIN, where]) == 0
    assert main(["eval", "tasks.n_random=2", f"eval.baselines=[{pid_baseline()}]", where]) == 0
    return runs


@pytest.fixture(scope="session")
def three_link_train(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, str]:
    """A store holding one short FINISHED train run of the three-link arm (its configured
    gains, 100-step episodes): (runs folder, run id). Tests may add eval and play runs."""
    from tests.helpers import stage_runs

    runs = tmp_path_factory.mktemp("three_link") / "runs"
    args = ["train", *SMALL_TRAIN, "robot=three_link", "train.gains=config"]
    assert main([*args, f"tracking.runs_dir={runs}"]) == 0
    (run,) = stage_runs(runs, "train")
    return runs, str(run.info.run_id)
