from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from omegaconf import DictConfig

from armexp.config import compose_config


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
