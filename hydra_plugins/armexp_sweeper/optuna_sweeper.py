"""``hydra/sweeper=optuna``: Hydra's Optuna sweeper interface on current Optuna.

Hydra's own plugin (hydra-optuna-sweeper 1.2/1.3) requires optuna < 3, whose database storage
does not run on SQLAlchemy 2, which MLflow's store and current Alembic need; this one keeps its
keys (``sampler`` with its seed, ``direction``, ``study_name``, ``storage``, ``n_trials``,
``n_jobs``, ``params``) and its search-space syntax. What differs: ``n_trials`` is the number of
trials the study holds when the sweep ends (re-running the command resumes the study), each
trial trains the seeds of ``hpo.seeds``, and the jobs are checked and tracked by armexp
(`armexp.hpo.sweep`). Optuna is imported only when a sweep runs, so Hydra's plugin scan works
without it.
"""

from __future__ import annotations

from typing import Any

from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class OptunaSweeper(Sweeper):
    def __init__(
        self,
        sampler: Any = None,
        direction: str = "maximize",
        study_name: str | None = None,
        storage: str | None = None,
        n_trials: int = 20,
        n_jobs: int = 1,
        params: Any = None,
    ) -> None:
        if direction not in ("maximize", "minimize"):
            raise ValueError(f"hydra.sweeper.direction={direction}: choose maximize or minimize")
        self.sampler, self.direction = sampler, direction
        self.study_name, self.storage = study_name, storage
        self.n_trials, self.n_jobs = int(n_trials), max(int(n_jobs), 1)
        self.params = params or {}
        self.job_idx = 0

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        from hydra.core.plugins import Plugins

        self.hydra_context = hydra_context
        self.config = config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config
        )

    def sweep(self, arguments: list[str]) -> Any:
        from armexp.hpo.sweep import run_sweep

        return run_sweep(self, arguments)
