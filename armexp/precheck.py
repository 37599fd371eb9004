"""What `armexp <stage>` checks before Hydra starts a job: a bad value is then one sentence and
exit code 2 (`ConfigError`), with no MLflow run, no sweep run and no Hydra folder left behind.

* Hydra's launcher settings (`armexp.launchers.check_settings`);
* every job's config, composed and validated for the stage (`armexp.config.jobs.JobComposer`:
  Hydra composes once per distinct choice of config groups, so a 200-job sweep is checked in
  seconds), and for `armexp hpo` its search (`armexp.hpo.checks`);
* for a command that runs a job (not ``--cfg job``): what the run would allocate against the
  memory available (`armexp.resources`), the runs folder (writable, room to start), and each run
  id of the config, which may be a prefix of one (`armexp.run_ids`): the overrides come back
  with the full ids, so the run's params record them.
"""

from __future__ import annotations

import re
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from omegaconf import OmegaConf

from armexp.config import ConfigError

#: A run id prefix inside an override's value.
_PREFIX = re.compile(r"(?<![0-9a-f])[0-9a-f]{4,31}(?![0-9a-f])")


def precheck(
    stage: str,
    overrides: Sequence[str],
    multirun: bool,
    search_path: Sequence[str] = (),
    runs_job: bool = True,
) -> list[str]:
    """Check the command's config (every job's, for ``multirun``); ``runs_job``: the command runs
    the stage (``--cfg job`` only prints). Returns ``overrides`` with run ids in full."""
    from armexp import launchers, resources
    from armexp.config.jobs import JobComposer
    from armexp.sweeps import sweep_combinations

    launchers.check_settings(overrides, search_path)
    jobs = sweep_combinations(overrides) if multirun else [list(overrides)]
    if multirun:
        print(
            f"armexp {stage}: checking the config of each of the {len(jobs)} jobs before any "
            "starts",
            flush=True,
        )
    composer = JobComposer(search_path, stage, share=len(jobs) > 1)
    prefixes: dict[str, tuple[str, Any]] = {}  # prefix -> (key, config of a job that has it)
    cfg = None
    for job in jobs:
        cfg = composer.compose(job)
        if stage == "hpo":
            from armexp.hpo.checks import check_hpo

            check_hpo(cfg, job, search_path)
        if runs_job:
            resources.check(cfg, stage, job)
            if stage in ("train", "pipeline", "hpo") and OmegaConf.select(cfg, "agent.device"):
                resources.device_here(str(cfg.agent.device))
            prefixes.update(_prefixes(cfg, prefixes))
    if not runs_job or cfg is None:
        return list(overrides)
    _writable(cfg)
    full = {value: _resolve(value, key, job_cfg) for value, (key, job_cfg) in prefixes.items()}
    return [_with_full_ids(o, full) for o in overrides] if full else list(overrides)


def _prefixes(cfg: Any, known: dict[str, tuple[str, Any]]) -> dict[str, tuple[str, Any]]:
    from armexp import run_ids

    return {
        value: (key, cfg)
        for key, value in run_ids.given(cfg)
        if not run_ids.is_full(value) and value not in known
    }


def _resolve(value: str, key: str, cfg: Any) -> str:
    from mlflow.tracking import MlflowClient

    from armexp import run_ids, store, tracking

    uri = tracking.store_uri(cfg, reading=True)
    return run_ids.resolve(MlflowClient(uri), value, key, store.hide_password(uri))


def _with_full_ids(override: str, full: dict[str, str]) -> str:
    """``override`` with each prefix of ``full`` in its value replaced by the full id, when its
    key takes run ids."""
    from armexp.config.run_keys import takes_ids

    key, eq, value = override.partition("=")
    if not eq or not takes_ids(key):
        return override
    return f"{key}={_PREFIX.sub(lambda m: full.get(m.group(0), m.group(0)), value)}"


def _writable(cfg: Any) -> None:
    """The runs folder (Hydra's job folders and the default store go there) can be made, the
    default store's artifacts folder in it written, and its disk has room to start
    (`armexp.disk.MIN_FREE_BYTES`)."""
    from armexp import disk

    folder = Path(str(cfg.tracking.runs_dir)).resolve()
    for place in (folder, folder / "artifacts"):
        try:
            if place == folder:
                folder.mkdir(parents=True, exist_ok=True)
            if place.is_dir():
                with tempfile.TemporaryFile(dir=place):
                    pass
        except OSError as exc:
            where = "there" if place == folder else f"in {place}"
            raise ConfigError(
                f"tracking.runs_dir={cfg.tracking.runs_dir} is not allowed: armexp cannot write "
                f"{where} ({exc.strerror}); give a folder you can write to."
            ) from None
    free = disk.free_bytes(folder)
    if free < disk.MIN_FREE_BYTES:
        raise ConfigError(
            f"tracking.runs_dir={cfg.tracking.runs_dir} is not allowed now: its disk is full "
            f"({free // 1024} KB free); free space and run again."
        )
