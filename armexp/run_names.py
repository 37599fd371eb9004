"""Run names that say what a run is, so a sweep's runs read at a glance in the MLflow UI.

``<stage>-<subject>-s<seed>``: ``simulate-pid-switching-s3`` (controller, scenario, seed),
``tune-pid-itae-s0`` (controller, criterion, ``tuner.seed``), ``train-sac_quick-s0`` and
``eval-sac_quick-s0`` (the policy's agent preset and, where the preset is another algorithm's,
``agent.algo``: ``train-sac_smoke-td3-s0``; seed), ``report``, ``pipeline-s0``, a study's
``study-s0-4``. A job of a sweep adds the swept values the name does not already show
(``tune-pid-itae-s0-tuner.pa=0.1``).
The user's ``<stage>.run_name`` wins.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from armexp.config.agent_schema import agent_label
from armexp.tags import AGENT_ALGO_TAG, AGENT_PRESET_TAG

#: Config keys each stage's name shows already; a sweep over one of them adds no suffix.
SHOWN: dict[str, tuple[str, ...]] = {
    "simulate": ("controller", "controller.name", "scenario", "scenario.kind", "seed"),
    "tune": ("controller", "controller.name", "tuner.objective.criterion", "tuner.seed"),
    "train": ("agent", "agent.algo", "seed"),
    "eval": ("seed",),
    "pipeline": ("seed", "pipeline.seeds"),
}


def run_name(cfg: DictConfig, stage: str, tags: Mapping[str, str] | None = None) -> str:
    """``<stage>.run_name`` when the user set one, else `describe`."""
    chosen = OmegaConf.select(cfg, f"{stage}.run_name", default=None)
    return str(chosen) if chosen else describe(cfg, stage, tags)


def describe(cfg: DictConfig, stage: str, tags: Mapping[str, str] | None = None) -> str:
    """The name of a ``stage`` run of ``cfg``; ``tags`` are the run's (the agent preset)."""
    study = stage == "pipeline" and bool(cfg.pipeline.seeds)
    parts = ["study" if study else stage, *_subject(cfg, stage, tags or {})]
    return "-".join([*parts, *_swept(cfg, stage)])


def _subject(cfg: DictConfig, stage: str, tags: Mapping[str, str]) -> list[str]:
    seed = f"s{cfg.seed}"
    if stage == "simulate":
        return [str(cfg.controller.name), str(cfg.scenario.kind), seed]
    if stage == "tune":
        return [str(cfg.controller.name), str(cfg.tuner.objective.criterion), f"s{cfg.tuner.seed}"]
    if stage in ("train", "eval", "play"):
        preset = agent_label(tags.get(AGENT_PRESET_TAG), tags.get(AGENT_ALGO_TAG))
        extra = [str(cfg.play.controller)] if stage == "play" and cfg.play.controller else []
        return [*([preset] if preset else []), *extra, seed]
    if stage == "pipeline":
        seeds = [int(s) for s in cfg.pipeline.seeds]
        return [f"s{_span(seeds)}"] if seeds else [seed]
    return []


def _span(seeds: Sequence[int]) -> str:
    """``0-4`` for consecutive seeds, else ``0,2,5``."""
    ordered = sorted(seeds)
    if len(ordered) > 2 and ordered == list(range(ordered[0], ordered[-1] + 1)):
        return f"{ordered[0]}-{ordered[-1]}"
    return ",".join(map(str, seeds))


def _swept(cfg: DictConfig, stage: str) -> list[str]:
    """The job's ``key=value`` overrides for the keys its sweep varies (``tracking.swept``, which
    ``armexp <stage> -m`` hands every job), less those the name shows."""
    keys = set(OmegaConf.select(cfg, "tracking.swept", default=None) or ())
    if not keys:
        return []
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return []
    shown = SHOWN.get(stage, ())
    out = []
    for override in HydraConfig.get().overrides.task:
        key = override.partition("=")[0].lstrip("+~")
        if key in keys and key not in shown:
            out.append(_short(override))
    return out


def _short(override: str) -> str:
    """``key=value`` with a float value in four significant digits (an optimising sweep's
    values come with seventeen)."""
    key, _, value = override.partition("=")
    if not any(c in value for c in ".eE"):
        return override
    try:
        return f"{key}={float(value):.4g}"
    except ValueError:
        return override
