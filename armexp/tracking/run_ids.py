"""Run ids as users type them: a full id, or a unique prefix of one, as git takes a commit's.

armexp prints the first 8 characters of a run id where a line is short (``policy of train run
1a2b3c4d``); every key that takes a run id (`KEYS`) and ``armexp diff`` accept such a prefix. One
resolver, `resolve`, serves them all: before a command runs, `armexp.precheck` writes the full
ids into its overrides (so its run's params record them); `armexp.tracking.lookup.find_stage_run`,
``armexp diff`` and the report's run selection resolve what reaches them otherwise (a config
file, a library call).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from typing import Any

from omegaconf import DictConfig, ListConfig

from armexp.config import ConfigError
from armexp.config.run_keys import KEYS, LISTS, MAPS, SINGLE
from armexp.tracking.tags import STAGE_TAG

__all__ = ["KEYS", "LISTS", "MAPS", "SINGLE", "given", "is_full", "resolve"]


FULL = re.compile(r"[0-9a-f]{32}")
#: The shortest prefix taken: git's.
MIN_PREFIX = 4
PREFIX = re.compile(rf"[0-9a-f]{{{MIN_PREFIX},32}}")
#: Candidates named when a prefix is ambiguous.
SHOWN = 5


def is_full(value: str) -> bool:
    return FULL.fullmatch(value) is not None


def _refuse(key: str, value: str, reason: str) -> ConfigError:
    """``key=value`` (or, for a list key, ``key contains value``) with ``reason``."""
    if key in LISTS:
        said = f"{key} contains {value}, which"
    else:  # a key (eval.train_run=…), or words (armexp diff's "run id …")
        said = f"{key} {value}" if " " in key else f"{key}={value}"
    return ConfigError(f"{said} is not allowed: {reason}.")


def resolve(client: Any, value: str, key: str, store: str) -> str:
    """The run id ``value`` names in the store of MLflow client ``client`` (its URI ``store``,
    for the sentences): a full id as it is (whether it exists is the caller's to say, with what
    else it must be), else the one run whose id starts with ``value``. ``key`` names where the
    value came from (``run id`` for `armexp diff`'s arguments). A value that is not hex, too
    short, ambiguous or unknown is a `ConfigError`."""
    from mlflow.entities import ViewType

    text = str(value)
    if is_full(text):
        return text
    if PREFIX.fullmatch(text) is None:
        raise _refuse(
            key, text,
            f"a run id is 32 hex digits, or a prefix of at least {MIN_PREFIX} of them (as armexp "
            "prints them)",
        )  # fmt: skip
    experiments = [e.experiment_id for e in client.search_experiments(view_type=ViewType.ALL)]
    found = client.search_runs(
        experiments, f"attributes.run_id LIKE '{text}%'", run_view_type=ViewType.ALL,
        max_results=SHOWN + 1,
    ) if experiments else []  # fmt: skip
    if not found:
        raise _refuse(key, text, f"no run id in the store {store} begins with {text}")
    if len(found) > 1:
        named = [f"{r.info.run_id} ({r.data.tags.get(STAGE_TAG) or 'not armexp'})"
                 for r in sorted(found, key=lambda r: r.info.run_id)[:SHOWN]]  # fmt: skip
        more = " and more" if len(found) > SHOWN else ""
        listed = ", ".join(named[:-1]) + f" and {named[-1]}" if not more else ", ".join(named)
        count = f"{len(found)}" if not more else f"more than {SHOWN}"
        raise _refuse(key, text, f"it begins {count} run ids, {listed}{more}; give more of the id")
    return str(found[0].info.run_id)


def given(cfg: DictConfig) -> Iterator[tuple[str, str]]:
    """(key, value) of every run id ``cfg`` holds at `KEYS` (a map's entries as
    ``<key>.<label>``)."""
    for key in SINGLE:
        value = _select(cfg, key)
        if value:
            yield key, str(value)
    for key in LISTS:
        for value in _select(cfg, key) or []:
            yield key, str(value)
    for key in MAPS:
        for label, value in (_select(cfg, key) or {}).items():
            if value:
                yield f"{key}.{label}", str(value)


def _select(cfg: DictConfig, key: str) -> Any:
    from omegaconf import OmegaConf

    node = OmegaConf.select(cfg, key, default=None)
    if isinstance(node, DictConfig | ListConfig):
        return OmegaConf.to_container(node)
    return node
