"""What `armexp hpo` checks before its first trial (called by `armexp.precheck`): one sentence
and exit code 2 for a missing Optuna or sampler package, an empty range, too few seeds, no
held-out checks, or a searched value whose config the train stage would refuse."""

from __future__ import annotations

from collections.abc import Sequence

from omegaconf import DictConfig

from armexp.config import ConfigError
from armexp.hpo import search, space, study


def check_hpo(cfg: DictConfig, overrides: Sequence[str], search_path: Sequence[str] = ()) -> None:
    from armexp.config import compose_config

    study.require("armexp hpo")
    name = str(cfg.hpo.sampler.name)
    module = study.SAMPLERS[name][1]
    if module:
        study.require(f"hpo.sampler.name={name}", module)
    found = space.from_mapping(cfg.hpo.params, cfg, "hpo.params.")
    if not found.distributions:
        raise ConfigError(
            "hpo.params={} is not allowed: give at least one key to search, e.g. "
            "'hpo.params={agent.learning_rate: tag(log, interval(1e-4,1e-2))}', or a preset "
            "(hpo=plain_sac)."
        )
    search.check_seeds(cfg.hpo.seeds)
    search.check_checks(cfg, "armexp hpo")
    for end in space.ends(found):
        try:
            compose_config([*search_path, *overrides, *end], stage="train")
        except ConfigError as exc:
            raise ConfigError(f"{str(exc).rstrip('.')} (a value the search can reach).") from None
