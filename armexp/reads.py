"""What a stage reads of the config: one declaration per stage, used both to run it and to hash it.

Each stage whose runs ``pipeline.reuse`` may reuse declares ``READS = Reads(stage, hashed=…,
unhashed=…)`` in its module: config keys (a key covers its whole subtree) whose values change the
stage's result (``hashed``), and keys it reads only to say where and how it records
(``unhashed``: ``<stage>.run_name``, ``<stage>.progress``, ``tracking``, …). An unhashed key may
sit under a hashed one (``eval`` hashed, ``eval.progress`` not).

* `Reads.view` is the config the stage runs on. Declared keys hold their resolved values; every
  other key holds an interpolation whose resolver raises `UndeclaredRead`, naming the stage and
  the key. Any read of an undeclared key — attribute, item, ``get``, ``OmegaConf.select`` with or
  without a default, ``to_container``, ``dict()`` — therefore raises at once, in tests and in use.
  The view is struct (a key that no config has raises too) and read-only (a write would not
  reach the config the run logs).
* `Reads.digest` is the hash of the hashed keys' resolved values (docs/design.md §2: a stage's
  reuse inputs are derived from what it reads), tagged ``armexp.inputs_hash`` on the stage's run
  (`armexp.tracking.stage_runs.stage_run`); `armexp.tracking.reuse` finds FINISHED runs by it.

A masked config with raising placeholders, rather than a masked copy or a proxy: a copy without
the undeclared keys answers ``cfg.get(key)`` and ``OmegaConf.select(cfg, key, default=…)`` with
the default, silently — the stale read this guards against —, and a read-recording proxy is not
a `DictConfig`, which OmegaConf, Hydra's ``instantiate`` and ``isinstance`` checks refuse or
bypass. The placeholders keep the config's shape, so code that walks it works unchanged.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import InterpolationResolutionError

#: The resolver behind the placeholders of undeclared keys.
RESOLVER = "armexp_undeclared"


class UndeclaredRead(InterpolationResolutionError):
    """A stage read a config key its `Reads` declaration does not list."""

    def __init__(self, stage: str, key: str) -> None:
        message = (
            f"the {stage} stage read the config key {key}, which its declaration of what it "
            f"reads (READS in its module) does not list; add {key} to its hashed keys if it "
            "changes the stage's result, else to its unhashed keys."
        )
        super().__init__(message)
        self.args = (message,)
        self.msg = message
        # Marks the error as complete, so OmegaConf re-raises it as it is instead of wrapping it.
        self._initialized = True
        self.stage, self.key = stage, key


#: Keys written into a placeholder as they are; any other is written in hex.
_PLAIN_KEY = re.compile(r"[\w.\-]+")
_HEX = "hex:"


def _undeclared(stage: str, key: str) -> Any:
    if key.startswith(_HEX):
        key = bytes.fromhex(key[len(_HEX) :]).decode()
    raise UndeclaredRead(stage, key)


if not OmegaConf.has_resolver(RESOLVER):
    OmegaConf.register_new_resolver(RESOLVER, _undeclared)


def _covers(keys: Iterable[str], key: str) -> bool:
    """Whether ``key`` is one of ``keys`` or inside one of them."""
    return any(key == k or key.startswith(f"{k}.") for k in keys)


def _plain(node: Any) -> Any:
    """A selected value as plain data, its interpolations resolved."""
    if isinstance(node, DictConfig | ListConfig):
        return OmegaConf.to_container(node, resolve=True)
    return node


def _drop(value: Any, path: list[str]) -> None:
    """Remove ``path`` (dotted parts) from nested dicts ``value``, where it is there."""
    for part in path[:-1]:
        if not isinstance(value, dict) or part not in value:
            return
        value = value[part]
    if isinstance(value, dict):
        value.pop(path[-1], None)


def digest(cfg: DictConfig, keys: Iterable[str], excluded: Iterable[str] = ()) -> str:
    """16 hex digits of SHA-256 over the resolved values of ``keys`` (sorted JSON), without the
    keys of ``excluded`` that lie inside them. Each value is selected in place, so
    interpolations (``tuner.seed: ${seed}``) resolve against the root."""
    skip = list(excluded)
    picked = {}
    for key in keys:
        value = _plain(OmegaConf.select(cfg, key))
        for inner in skip:
            if inner.startswith(f"{key}."):
                _drop(value, inner[len(key) + 1 :].split("."))
        picked[key] = {"v": value}  # the shape every armexp.inputs_hash was made from
    text = json.dumps(picked, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _placeholder(stage: str, key: str) -> str:
    """The interpolation that stands for undeclared ``key``: it raises `UndeclaredRead`."""
    written = key if _PLAIN_KEY.fullmatch(key) else _HEX + key.encode().hex()
    return f"${{{RESOLVER}:{stage},'{written}'}}"


@dataclass(frozen=True)
class Reads:
    """The config keys a stage reads: ``hashed`` change its result, ``unhashed`` do not.
    ``earlier``: the hashed keys of the stage's earlier declarations, newest first; runs made
    under one carry its digest (`Reads.earlier_digests`), and `armexp.tracking.reuse` takes
    them where their logged config matches this declaration's hashed keys."""

    stage: str
    hashed: tuple[str, ...]
    unhashed: tuple[str, ...] = ()
    earlier: tuple[tuple[str, ...], ...] = ()

    def __post_init__(self) -> None:
        both = set(self.hashed) & set(self.unhashed)
        inside = [k for k in self.hashed if _covers(self.unhashed, k)]
        if both or inside:
            raise ValueError(
                f"{self.stage}'s reads: {sorted(both or inside)} cannot be hashed inside or as "
                "an unhashed key."
            )

    @property
    def declared(self) -> tuple[str, ...]:
        return (*self.hashed, *self.unhashed)

    def hashes(self, key: str) -> bool:
        """Whether the digest covers ``key`` (a dotted key, e.g. a param's name)."""
        return _covers(self.hashed, key) and not _covers(self.unhashed, key)

    def digest(self, cfg: DictConfig) -> str:
        """The hash of the hashed keys' resolved values in ``cfg``: equal digests, equal
        inputs."""
        return digest(cfg, self.hashed, self.unhashed)

    def earlier_digests(self, cfg: DictConfig) -> list[str]:
        """The digests ``cfg`` had under the earlier declarations, newest first."""
        return [digest(cfg, keys, self.unhashed) for keys in self.earlier]

    def view(self, cfg: DictConfig) -> DictConfig:
        """``cfg`` as the stage may read it: declared keys resolved, any other key a placeholder
        that raises `UndeclaredRead` when read."""
        out = OmegaConf.create(self._masked(cfg, cfg, ""))
        OmegaConf.set_struct(out, True)
        OmegaConf.set_readonly(out, True)
        return out

    def _masked(self, root: DictConfig, node: DictConfig, path: str) -> dict[str, Any]:
        out: dict[str, Any] = {}
        for name in node:
            key = str(name)
            full = f"{path}.{key}" if path else key
            if _covers(self.declared, full):
                out[key] = _plain(OmegaConf.select(root, full))
                continue
            child = OmegaConf.select(root, full) if self._holds_declared(full) else None
            if isinstance(child, DictConfig):
                out[key] = self._masked(root, child, full)
            else:
                out[key] = _placeholder(self.stage, full)
        return out

    def _holds_declared(self, key: str) -> bool:
        return any(k.startswith(f"{key}.") for k in self.declared)
