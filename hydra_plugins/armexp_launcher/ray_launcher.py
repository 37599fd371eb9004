"""Hydra's Ray launcher, with a sweep that outlives a dead worker (``hydra/launcher=ray``).

Hydra's launcher collects its jobs with ``ray.get`` one after another, so a worker killed mid-job
(the OOM killer, a lost node, SIGKILL) raises out of the launcher while the other jobs still run,
and they die with the driver. `RayLauncher` waits for every job and turns a lost one into a
FAILED job result instead: the other points finish, the store marks the lost point's runs FAILED
(`armexp.tracking.sweeps.close_sweep`), and ``pipeline.reuse=true`` on the same command
completes only the points that are missing. Tasks are not retried (``max_retries: 0`` in the
config): a point that died is re-run by the user, not silently.

Hydra imports every module of ``hydra_plugins`` when it looks for plugins, so Ray and Hydra's
Ray plugin are imported only when this launcher is set up (``armexp[cluster]``).
"""

from __future__ import annotations

import logging
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from hydra.core.singleton import Singleton
from hydra.core.utils import JobReturn, JobStatus, configure_log, filter_overrides, setup_globals
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, open_dict

log = logging.getLogger(__name__)


class JobLost(RuntimeError):
    """A sweep job whose Ray worker or node died; Hydra raises it after the sweep's other
    jobs finished."""


class RayLauncher(Launcher):
    """Hydra's Ray launcher (same config: ``ray.init``, ``ray.remote``); every job of the batch
    is collected, and a job whose worker died is a FAILED result."""

    def __init__(self, ray: DictConfig) -> None:
        self.ray_cfg = ray
        self.hydra_context: HydraContext | None = None
        self.task_function: TaskFunction | None = None
        self.config: DictConfig | None = None

    def setup(
        self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig
    ) -> None:
        self.config, self.hydra_context, self.task_function = config, hydra_context, task_function

    def launch(
        self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int
    ) -> Sequence[JobReturn]:
        import ray
        from hydra_plugins.hydra_ray_launcher._launcher_util import launch_job_on_ray, start_ray

        assert self.config is not None and self.hydra_context is not None
        assert self.task_function is not None
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        start_ray(self.ray_cfg.init)
        started = time.time()
        jobs: list[tuple[Any, int, list[str], Any]] = []
        for offset, overrides in enumerate(job_overrides):
            idx = initial_job_idx + offset
            log.info("\t#%d : %s", idx, " ".join(filter_overrides(overrides)))
            sweep_config = self.hydra_context.config_loader.load_sweep_config(
                self.config, list(overrides)
            )
            with open_dict(sweep_config):
                sweep_config.hydra.job.id = f"job_id_for_{idx}"
                sweep_config.hydra.job.num = idx
            ref = launch_job_on_ray(
                self.hydra_context,
                self.ray_cfg.remote,
                sweep_config,
                self.task_function,
                Singleton.get_state(),
            )
            jobs.append((ref, idx, list(overrides), sweep_config))
        results: list[JobReturn] = []
        for ref, idx, overrides, sweep_config in jobs:
            try:
                results.append(ray.get(ref))
            except ray.exceptions.RayError as exc:  # the job's worker or node died
                reason = str(exc).strip().splitlines()[0][:300]
                lost = JobLost(f"sweep job #{idx} ({' '.join(overrides)}) was lost: {reason}")
                print(f"armexp: {lost}", file=sys.stderr)
                results.append(
                    JobReturn(
                        overrides=overrides,
                        cfg=sweep_config,
                        hydra_cfg=sweep_config,
                        status=JobStatus.FAILED,
                        _return_value=lost,
                    )
                )
        log.info("Ray ran %d jobs in %.1f s", len(results), time.time() - started)
        return results
