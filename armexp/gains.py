"""Where a controller's gains come from: the one resolver train, eval and play use.

A controller's gains are either configured (``controller.gains`` as composed, or the controller's
per-robot defaults, ``conf/per_robot/<controller>_<robot>.yaml``) or those of a tune run: one given
by id, or the latest FINISHED tune run with that controller, robot and tuning criterion, one of
the config's ``tuner.seed`` first (docs/design.md §5). `resolve` returns them typed (`Gains`: the
values in config form, the criterion and horizon they were tuned under, the tune run) so callers
record their source.
`train_source` says which of the two train takes, from ``train.gains`` and what the command typed:
gains typed on a train or pipeline command (``controller.gains=paper``) are trained with.

The criterion of a tune run is its param ``tuner.objective.criterion`` (or its tag
``armexp.criterion``); tune runs made before the criterion was a choice have neither and are
criterion ``gaing`` (the paper's W) over 0.6 s, or the horizon they logged.
"""

from __future__ import annotations

import contextlib
import copy
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import yaml
from mlflow.entities import Run
from omegaconf import DictConfig, OmegaConf, open_dict

from armexp.baselines import CONFIG
from armexp.config import ConfigError
from armexp.sim.controllers import without_adaptation as _without_adaptation
from armexp.tracking import artifacts, lookup
from armexp.tracking.tags import CRITERION_TAG, HORIZON_TAG
from armexp.tune.objective import resolved_horizon

#: The tune run's param and tags that say what it was tuned under.
CRITERION_PARAM = "tuner.objective.criterion"
HORIZON_PARAM = "tuner.objective.horizon"
#: What a tune run without a criterion was tuned under: the paper's W over 0.6 s.
OLD_CRITERION, OLD_HORIZON = "gaing", 0.6

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Gains:
    """A controller's gains in config form (``{"a0": …}`` / ``{"kp": [...], …}``), the
    criterion they were tuned under (``config`` for configured gains), the horizon (s; None for
    configured gains) and the tune run they came from (None for configured gains)."""

    controller: str
    values: dict[str, Any]
    criterion: str
    horizon: float | None
    tune_run: str | None


def criterion_of(cfg: DictConfig) -> str:
    """The tuning criterion a config asks for (``tuner.objective.criterion``): the comparison's
    criterion in eval and pipeline, the criterion a tune run is looked up by in train."""
    return str(cfg.tuner.objective.criterion)


def with_criterion(cfg: DictConfig, criterion: str) -> DictConfig:
    """A copy of ``cfg`` that tunes under ``criterion`` (its horizon as configured)."""
    out = copy.deepcopy(cfg)
    with open_dict(out):
        out.tuner.objective.criterion = criterion
    return out


def comparison_horizon(cfg: DictConfig, criterion: str) -> float:
    """The horizon of ``criterion`` under this config's ``tuner.objective.horizon``."""
    return resolved_horizon(criterion, cfg.tuner.objective.horizon)


def run_criterion(run: Run) -> str:
    """The criterion a tune run was tuned under (``gaing`` for runs made before the choice)."""
    return str(
        run.data.tags.get(CRITERION_TAG) or run.data.params.get(CRITERION_PARAM) or OLD_CRITERION
    )


def run_horizon(run: Run) -> float:
    """The horizon (s) a tune run's criterion was evaluated over."""
    if HORIZON_TAG in run.data.tags:
        return float(run.data.tags[HORIZON_TAG])
    logged = _number(run.data.params.get(HORIZON_PARAM))
    if CRITERION_PARAM in run.data.params or CRITERION_TAG in run.data.tags:
        return resolved_horizon(run_criterion(run), logged)
    return OLD_HORIZON if logged is None else logged


def _number(text: str | None) -> float | None:
    try:
        value = float(text) if text is not None else None
    except ValueError:
        return None
    return value if value is not None and math.isfinite(value) else None


def configured(cfg: DictConfig, controller: str, robot: str) -> Gains:
    """Configured gains: ``cfg.controller.gains`` when ``cfg`` composes that controller and
    robot (with the user's overrides), else the controller's defaults for the robot."""
    if str(cfg.controller.name) == controller and str(cfg.robot.name) == robot:
        node = cfg.controller.gains
    else:
        from armexp.config import compose_config

        node = compose_config([f"controller={controller}", f"robot={robot}"]).controller.gains
    values = OmegaConf.to_container(node, resolve=True)
    assert isinstance(values, dict)
    return Gains(controller, {str(k): v for k, v in values.items()}, CONFIG, None, None)


def tuned(
    cfg: DictConfig,
    controller: str,
    robot: str,
    criterion: str,
    run_id: str | None = None,
    key: str = "tune_run",
) -> Gains:
    """The gains of tune run ``run_id``, or of the latest FINISHED tune run of ``controller`` on
    ``robot`` under ``criterion``, in ``cfg``'s store: of those, one tuned with ``cfg``'s
    ``tuner.seed`` where one is, else the latest of any seed with a warning. A given run of
    another controller, robot or criterion is a `ConfigError` naming ``key``."""
    match = {"controller.name": controller, "robot.name": robot}

    def latest(params: dict[str, str]) -> Run:
        return lookup.find_stage_run(
            cfg, "tune", run_id=run_id, match=params, key=key,
            accept=lambda r: run_criterion(r) == criterion,
            wanted=f"{CRITERION_PARAM}={criterion}",
        )  # fmt: skip

    # A seeded study (``experiment=reproduce``: ``tuner.seed: ${seed}``) tunes every seed into one
    # store; a stage run by hand at seed 1001 means seed 1001's tune, not the newest of any seed.
    seed = None if run_id else OmegaConf.select(cfg, "tuner.seed")
    run = None
    if seed is not None:
        with contextlib.suppress(ConfigError):
            run = latest({**match, "tuner.seed": str(seed)})
    if run is None:
        run = latest(match)
        if seed is not None:
            log.warning(
                "%s: no FINISHED tune run of %s with tuner.seed=%s; using the latest, %s "
                "(tuner.seed=%s); pass %s=<run id> to choose", key, controller, seed,
                run.info.run_id, run.data.params.get("tuner.seed"), key,
            )  # fmt: skip
    for param, value in match.items():
        got = run.data.params.get(param)
        if got != value:
            raise ConfigError(
                f"{key}={run.info.run_id} is not allowed: that tune run has {param}={got}, and "
                f"{param}={value} is needed here."
            )
    got = run_criterion(run)
    if got != criterion:
        raise ConfigError(
            f"{key}={run.info.run_id} is not allowed: that tune run was tuned under "
            f"{CRITERION_PARAM}={got}, and {criterion} is needed here."
        )
    values = yaml.safe_load(
        artifacts.download_artifact(run.info.run_id, "gains.yaml", cfg).read_text()
    )
    return Gains(controller, values, criterion, run_horizon(run), run.info.run_id)


def resolve(
    cfg: DictConfig,
    controller: str,
    robot: str,
    source: str,
    criterion: str | None = None,
    run_id: str | None = None,
    key: str = "tune_run",
) -> Gains:
    """Gains of ``controller`` on ``robot`` from ``source``: ``config`` (`configured`) or
    ``tuned`` (`tuned`: tune run ``run_id`` or the latest under ``criterion``, by default the
    criterion ``cfg`` asks for)."""
    if source == CONFIG:
        return configured(cfg, controller, robot)
    return tuned(cfg, controller, robot, criterion or criterion_of(cfg), run_id, key)


#: Command-line keys that choose the controller's gains themselves (``controller.gains=paper``,
#: ``controller/gains=paper``, ``controller.gains.a0=…``).
_GAINS_KEYS = ("controller.gains", "controller/gains")


def train_source(cfg: DictConfig, overrides: Sequence[str]) -> str:
    """Where train takes the controller's gains from, given the command's ``overrides``:
    ``train.gains`` when the command sets it; else ``config`` when the command chooses the
    controller's gains (a train command that types gains means "train with these", not "with a
    tune run's"); else ``train.gains`` as composed (``tuned`` by default)."""
    keys = [o.lstrip("+~").partition("=")[0] for o in overrides]
    if "train.gains" in keys:
        return str(cfg.train.gains)
    if any(k in _GAINS_KEYS or k.startswith(f"{_GAINS_KEYS[0]}.") for k in keys):
        return CONFIG
    return str(cfg.train.gains)


def with_train_source(cfg: DictConfig, overrides: Sequence[str]) -> DictConfig:
    """``cfg`` with ``train.gains`` set to `train_source` (a copy when that changes it, ``cfg``
    itself otherwise), so the run's params and its reuse digest record where its gains came from."""
    source = train_source(cfg, overrides)
    if source == str(cfg.train.gains):
        return cfg
    out = copy.deepcopy(cfg)
    with open_dict(out):
        out.train.gains = source
    return out


def job_overrides() -> list[str]:
    """The command-line overrides of the running Hydra job (none outside one, e.g. a library
    call): what `train_source` is given by the stages."""
    from hydra.core.hydra_config import HydraConfig

    return list(HydraConfig.get().overrides.task) if HydraConfig.initialized() else []


def without_adaptation(values: dict[str, Any]) -> dict[str, Any]:
    """The adaptive law's gains with adaptation off (b1 = 0, so ρ̂ ≡ 0): the ablation."""
    return dict(_without_adaptation(values))
