"""The configs of many jobs (a sweep's) from few Hydra compositions.

Hydra composes a config in two steps: the defaults list with the group choices (``robot=…``,
``experiment=…``, ``+``/``~`` edits, Hydra's own settings), then each plain ``key=value``
override applied to the result with ``OmegaConf.update`` (`ConfigLoaderImpl`'s
``_apply_overrides_to_config``). The first step costs a few hundred milliseconds; the second
almost nothing. A sweep's jobs mostly share their group choices and differ in values
(``tuner.seed=range(0,200)``), so `JobComposer` runs the first step once per distinct choice of
groups and the second per job, on a copy. The first job of each choice is also composed in full
by Hydra and compared: a difference (a case this reading of Hydra's steps misses) sends that
choice's jobs through Hydra in full.
"""

from __future__ import annotations

import copy
import re
from collections.abc import Sequence
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.override_parser.types import Override, OverrideType
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from armexp import config
from armexp.config import config_dir, normalize_overrides, validate

_SEARCHPATH = re.compile(r"^\+*hydra\.searchpath=\[(.*)\]$")


class JobComposer:
    """Composes and validates jobs' configs (for ``stage``; ``search_path``: the overrides that
    add ``--config-dir`` folders), sharing Hydra's work between jobs with the same groups."""

    def __init__(
        self, search_path: Sequence[str] = (), stage: str | None = None, share: bool = True
    ) -> None:
        self.search_path = list(search_path)
        self.stage = stage
        #: Whether jobs will share compositions (False for a single job: Hydra composes it).
        self.share = share
        #: Group choices -> their composition without the plain values (None: compose in full).
        self._bases: dict[tuple[str, ...], DictConfig | None] = {}
        #: How many times Hydra composed (for tests and benchmarks).
        self.compositions = 0

    def _hydra(self, overrides: Sequence[str]) -> DictConfig:
        self.compositions += 1
        return config.compose_unchecked([*self.search_path, *overrides])

    def compose(self, overrides: Sequence[str]) -> DictConfig:
        """The validated config of one job, as `armexp.config.compose_config` gives it."""
        normalized = normalize_overrides(overrides)
        parsed = OverridesParser.create().parse_overrides(normalized)
        groups = _group_folders([*self.search_path, *normalized])
        if not self.share or groups is None or any(o.is_sweep_override() for o in parsed):
            cfg = self._hydra(normalized)  # says what is wrong, or composes as Hydra does
        else:
            plain = [o for o in parsed if _is_plain(o, groups)]
            choice = tuple(str(o.input_line) for o in parsed if not _is_plain(o, groups))
            cfg = self._from_choice(choice, plain, normalized)
        validate(cfg, self.stage)
        return cfg

    def _from_choice(
        self, choice: tuple[str, ...], plain: list[Override], normalized: list[str]
    ) -> DictConfig:
        if choice not in self._bases:
            full = self._hydra(normalized)  # the first job: Hydra's own, and the reference
            try:
                base = self._hydra(list(choice))
                same = _to_plain(_apply(base, plain)) == _to_plain(full)
            except (config.ConfigError, OmegaConfBaseException):
                same = False
            self._bases[choice] = base if same else None
            return full
        shared = self._bases[choice]
        if shared is None:
            return self._hydra(normalized)
        try:
            return _apply(shared, plain)
        except OmegaConfBaseException:
            return self._hydra(normalized)  # Hydra's own sentence for the bad value


def _apply(base: DictConfig, plain: list[Override]) -> DictConfig:
    """``base`` with each plain override applied as Hydra applies it."""
    cfg = copy.deepcopy(base)
    for override in plain:
        OmegaConf.update(cfg, override.key_or_group, override.value(), merge=True)
    return cfg


def _to_plain(cfg: DictConfig) -> object:
    return OmegaConf.to_container(cfg)


def _is_plain(override: Override, groups: list[Path]) -> bool:
    """A ``key=value`` override of a value (not of a config group, not Hydra's, no ``+``/``~``
    edit and no ``@package``)."""
    if override.is_hydra_override() or override.package is not None:
        return False
    if override.type is not OverrideType.CHANGE:
        return False
    key = override.key_or_group
    return "/" not in key and not any((g / key.replace(".", "/")).is_dir() for g in groups)


def _group_folders(overrides: Sequence[str]) -> list[Path] | None:
    """The folders config groups come from: armexp's tree and each ``file://`` entry of
    ``hydra.searchpath``; None when the search path has another kind (``pkg://``), whose groups
    cannot be listed here."""
    folders = [config_dir()]
    for override in overrides:
        found = _SEARCHPATH.match(override)
        if not found:
            continue
        for entry in filter(None, (e.strip().strip("'\"") for e in found.group(1).split(","))):
            if not entry.startswith("file://"):
                return None
            folders.append(Path(entry[len("file://") :]))
    return folders
