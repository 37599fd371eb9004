"""The search space in Hydra's sweep grammar, as Optuna distributions.

Both the Optuna sweeper (``armexp train -m hydra/sweeper=optuna 'agent.gamma=interval(0.9,0.999)'``)
and `armexp hpo` (``hpo.params: {agent.gamma: interval(0.9,0.999)}``) read the same syntax, parsed
by Hydra's own override parser:

* ``interval(low, high)``: a float in [low, high]; an integer where the key's value in the config
  is one (``agent.batch_size``) or with ``tag(int, …)``; ``tag(log, interval(…))`` samples its
  logarithm;
* ``range(start, stop[, step])``: the values of Hydra's range (``stop`` excluded, as the basic
  sweeper's ``-m`` grid runs them);
* ``choice(a, b, …)``: one of the values, lists included (``choice([64,64],[256,256])``).

A plain value (``agent.gamma=0.99``) is fixed for every trial.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import (
    ChoiceSweep,
    IntervalSweep,
    Override,
    RangeSweep,
    Transformer,
)
from hydra.errors import HydraException
from omegaconf import DictConfig, OmegaConf

from armexp.config import ConfigError

#: Keys a trial sets itself: its seeds come from ``hpo.seeds``, its runs' places from the search.
NOT_SEARCHED = ("seed", "tracking.sweep_run", "tracking.swept")


@dataclass
class Space:
    """What a search varies (Optuna distributions by config key) and what it fixes."""

    distributions: dict[str, Any] = field(default_factory=dict)
    #: How each key was written (``interval(1e-4,1e-2)``), for messages and the HPO run.
    written: dict[str, str] = field(default_factory=dict)
    fixed: list[str] = field(default_factory=list)

    def overrides(self, params: Mapping[str, Any]) -> list[str]:
        """A trial's values as overrides (choices are kept as Hydra writes them)."""
        return [*self.fixed, *(f"{key}={_text(value)}" for key, value in params.items())]

    def suggest(self, trial: Any) -> dict[str, Any]:
        """Ask ``trial`` for a value of every key (a re-queued trial gets its fixed ones)."""
        import optuna.distributions as d

        values: dict[str, Any] = {}
        for key, dist in self.distributions.items():
            if isinstance(dist, d.CategoricalDistribution):
                values[key] = trial.suggest_categorical(key, dist.choices)
            elif isinstance(dist, d.IntDistribution):
                values[key] = trial.suggest_int(key, dist.low, dist.high, step=dist.step,
                                                log=dist.log)  # fmt: skip
            else:
                values[key] = trial.suggest_float(key, dist.low, dist.high, step=dist.step,
                                                  log=dist.log)  # fmt: skip
        return values


def _text(value: Any) -> str:
    return repr(value) if isinstance(value, float) else str(value)


def parse(overrides: Sequence[str], cfg: DictConfig | None = None, where: str = "") -> Space:
    """The space of ``overrides`` (``key=interval(…)`` and plain ``key=value``); ``cfg`` tells
    integer keys; ``where`` prefixes the key in messages (``hpo.params.``)."""
    space = Space()
    parser = OverridesParser.create()
    for text in overrides:
        try:
            (override,) = parser.parse_overrides([text])
        except HydraException as exc:
            raise ConfigError(f"{where}{text} is not allowed: it does not parse ({exc}).") from None
        if override.is_hydra_override():
            continue
        key = override.get_key_element().lstrip("+~")
        if key in NOT_SEARCHED:
            if override.is_sweep_override():
                raise ConfigError(
                    f"{where}{text} is not allowed: a trial sets {key} itself (its seeds are "
                    "hpo.seeds); search other keys."
                )
            continue
        if not override.is_sweep_override():
            space.fixed.append(text)
            continue
        value = override.value()
        space.written[key] = text.partition("=")[2]
        space.distributions[key] = distribution(override, value, _is_int(cfg, key), where)
    return space


def as_params(overrides: Sequence[str]) -> list[str]:
    """`armexp hpo`'s command line: a sweep (``'agent.gamma=interval(0.9,0.999)'``, or
    ``hpo.params.agent.gamma=…``) is an entry of ``hpo.params`` (a string, as in a preset), so the
    stage takes the sweeper's syntax and Hydra composes one config."""
    parser = OverridesParser.create()
    out = []
    for text in overrides:
        try:
            (override,) = parser.parse_overrides([text])
        except HydraException:
            out.append(text)  # reported by the checks that follow
            continue
        if not override.is_sweep_override() or override.is_hydra_override():
            out.append(text)
            continue
        key = override.get_key_element().lstrip("+~").removeprefix("hpo.params.")
        value = text.partition("=")[2].replace("\\", "\\\\").replace("'", "\\'")
        out.append(f"++hpo.params.{key}='{value}'")
    return out


def from_mapping(params: Mapping[str, Any], cfg: DictConfig | None, where: str) -> Space:
    """The space of a ``{key: "interval(…)"}`` mapping (``hpo.params``); a key given on the
    command line (``hpo.params.agent.gamma=…``) arrives nested, and is read as ``agent.gamma``."""
    return parse([f"{key}={value}" for key, value in _flat(params, "").items()], cfg, where)


def _flat(node: Any, prefix: str) -> dict[str, Any]:
    if not isinstance(node, Mapping | DictConfig):
        return {prefix: node}
    out: dict[str, Any] = {}
    for key, value in node.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def _is_int(cfg: DictConfig | None, key: str) -> bool:
    if cfg is None:
        return False
    value = OmegaConf.select(cfg, key, default=None)
    return isinstance(value, int) and not isinstance(value, bool)


def distribution(override: Override, value: Any, int_key: bool, where: str = "") -> Any:
    """The Optuna distribution of one sweep override; an empty one is one sentence."""
    import optuna.distributions as d

    text = f"{where}{override.input_line}"
    if isinstance(value, ChoiceSweep):
        choices: list[Any] = list(override.sweep_iterator(transformer=Transformer.encode))
        if value.shuffle:
            raise ConfigError(f"{text} is not allowed: a search draws its own order; drop shuffle.")
        return d.CategoricalDistribution(choices)
    if isinstance(value, RangeSweep):
        values: list[Any] = list(override.sweep_iterator(transformer=Transformer.identity))
        if not values:
            raise ConfigError(
                f"{text} is not allowed: the range is empty; give range(start, stop[, step]) "
                "with at least one value before stop."
            )
        if value.shuffle or any(isinstance(v, float) for v in values):
            return d.CategoricalDistribution(values)
        step = int(value.step or 1)
        if step < 0:
            values.reverse()
            step = -step
        return d.IntDistribution(int(values[0]), int(values[-1]), step=step)
    assert isinstance(value, IntervalSweep)
    low, high = float(value.start or 0.0), float(value.end or 0.0)
    if not low < high:
        raise ConfigError(
            f"{text} is not allowed: the interval is empty; give interval(low, high) with "
            "low < high."
        )
    log = "log" in value.tags
    if log and low <= 0:
        raise ConfigError(
            f"{text} is not allowed: a log interval needs low > 0; give tag(log, "
            "interval(low, high)) with 0 < low < high."
        )
    if "int" in value.tags or (int_key and low.is_integer() and high.is_integer()):
        lo, hi = math.ceil(low), math.floor(high)
        if lo >= hi:
            raise ConfigError(
                f"{text} is not allowed: the interval holds fewer than two integers; widen it."
            )
        return d.IntDistribution(lo, hi, log=log)
    return d.FloatDistribution(low, high, log=log)


def ends(space: Space) -> list[list[str]]:
    """Overrides at the ends of every searched key (low ends, high ends, each choice), so the
    config of the values a search can reach is checked before the first trial."""
    import optuna.distributions as d

    lows, highs, extra = [], [], []
    for key, dist in space.distributions.items():
        if isinstance(dist, d.CategoricalDistribution):
            lows.append(f"{key}={_text(dist.choices[0])}")
            highs.append(f"{key}={_text(dist.choices[-1])}")
            extra += [[f"{key}={_text(c)}"] for c in dist.choices[1:-1]]
        else:
            lows.append(f"{key}={_text(dist.low)}")
            highs.append(f"{key}={_text(dist.high)}")
    return [lows, highs, *extra] if lows else []
