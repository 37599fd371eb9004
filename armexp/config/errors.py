"""One sentence for a Hydra or OmegaConf error, built from the exception's fields.

Hydra and OmegaConf say what went wrong in structured exceptions: the override that does not
parse (`OverrideParseException.override`), the config file not found and the group's options
(`MissingConfigException.missing_cfg_file`, ``.options``), the key, value and owning schema of a
rejected value (`omegaconf.errors.OmegaConfBaseException`: ``full_key``, ``value``,
``object_type``). The sentence names the key, the value and what is allowed; what is allowed
for a typed field is read from the schema's type hints.
"""

from __future__ import annotations

import dataclasses
import enum
import types
import typing
from collections.abc import Sequence
from typing import Any

from hydra.errors import MissingConfigException, OverrideParseException
from omegaconf.errors import (
    ConfigAttributeError,
    ConfigIndexError,
    ConfigKeyError,
    OmegaConfBaseException,
    ValidationError,
)

from armexp.config.checks import ConfigError
from armexp.config.schema import SCHEMAS

SEE_KEYS = "see `armexp <stage> --cfg job` for the valid keys"


def translate_error(exc: BaseException, overrides: Sequence[str] = ()) -> ConfigError:
    """One sentence for a composition error (``overrides``: the command's, to show a value as
    the user wrote it)."""
    if isinstance(exc, OverrideParseException):
        # Hydra's message: "Error parsing override '…'" (when nothing more precise), the
        # parser's reason, then a link to the grammar.
        lines = [ln for ln in exc.message.splitlines() if ln.strip()]
        said = [ln for ln in lines if not ln.startswith(("Error parsing override", "See http"))]
        reason = _first_line(said[0] if said else "")
        return ConfigError(
            f"{exc.override} is not a valid override ({reason}); write key=value as in Hydra's "
            "override grammar (https://hydra.cc/docs/advanced/override_grammar/basic/)."
        )
    if isinstance(exc, MissingConfigException) and exc.missing_cfg_file and exc.options:
        group, _, option = exc.missing_cfg_file.rpartition("/")
        # The schemas armexp registers in Hydra's ConfigStore are in the group but not choices.
        options = [o for o in exc.options if f"{group}/{o}" not in SCHEMAS]
        return ConfigError(
            f"{_as_written(group, overrides)}={option} is not a known option; choose one of: "
            f"{', '.join(options)}."
        )
    cause = exc if isinstance(exc, OmegaConfBaseException) else exc.__cause__
    if isinstance(cause, OmegaConfBaseException) and cause.full_key:
        return _value_error(cause, overrides)
    return ConfigError(f"the configuration could not be composed: {_first_line(str(exc))}.")


def _value_error(exc: OmegaConfBaseException, overrides: Sequence[str]) -> ConfigError:
    key = str(exc.full_key)
    if isinstance(exc, ConfigAttributeError | ConfigKeyError):
        return ConfigError(
            f"{key} is not a config key armexp knows here (from '{_find_override(key, overrides)}')"
            f"; {SEE_KEYS}."
        )
    written = _find_override(key, overrides)
    if isinstance(exc, ConfigIndexError):
        owner = key.rpartition("[")[0]
        return ConfigError(
            f"{written} is not allowed: {owner} has no entry [{exc.key}]; give the whole list "
            f"instead ({owner}=[...])."
        )
    value = _override_value(key, overrides)
    shown = value if value is not None else str(exc.value)
    if isinstance(exc, ValidationError):
        return ConfigError(f"{key}={shown} is not allowed: it must be {_expected(exc)}.")
    return ConfigError(f"{key}={shown} is not allowed: {_first_line(str(exc.msg))}.")


def _expected(exc: OmegaConfBaseException) -> str:
    """What the config declares for the rejected key, in words: a list's element type, or the
    owning schema's type hint for the field."""
    entries = typing.get_args(exc.ref_type)
    if exc.object_type in (list, tuple) and entries:
        return _describe(entries[0])
    try:
        declared = typing.get_type_hints(exc.object_type)[str(exc.key)]
    except Exception:  # not a schema's field (a plain dict's key): no declared type
        return "of the type the config declares"
    return _describe(declared)


def _describe(kind: Any) -> str:
    origin, args = typing.get_origin(kind), typing.get_args(kind)
    if origin in (typing.Union, types.UnionType):
        words = [_describe(a) for a in args if a is not type(None)]
        return " or ".join(words) + (", or null" if type(None) in args else "")
    if origin is typing.Literal:
        return "one of: " + ", ".join(map(str, args))
    if kind in (list, tuple) or origin in (list, tuple, Sequence):
        return "a list in brackets, e.g. [1.0, 0.8]"
    if kind is dict or origin is dict or dataclasses.is_dataclass(kind):
        return "a group of settings (see `armexp <stage> --cfg job`)"
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return "one of: " + ", ".join(m.name for m in kind)
    plain = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}
    return plain.get(kind, f"of type {getattr(kind, '__name__', kind)}")


def _first_line(text: str) -> str:
    lines = text.strip().splitlines()
    return lines[0].rstrip(".") if lines else "no reason given"


def _as_written(group: str, overrides: Sequence[str]) -> str:
    """A config group as the command wrote it (``controller.gains`` or ``controller/gains``)."""
    for o in overrides:
        key = o.lstrip("+~").partition("=")[0]
        if key.replace(".", "/") == group:
            return key
    return group.replace("/", ".") if not group.startswith("hydra/") else group


def _same_key(written: str, full_key: str) -> bool:
    """``robot.lengths.0`` on the command line is OmegaConf's ``robot.lengths[0]``."""
    return written == full_key or written == full_key.replace("[", ".").replace("]", "")


def _override_value(key: str, overrides: Sequence[str]) -> str | None:
    for o in overrides:
        k, _, v = o.lstrip("+~").partition("=")
        if _same_key(k, key):
            return v
    return None


def _find_override(key: str, overrides: Sequence[str]) -> str:
    for o in overrides:
        if _same_key(o.lstrip("+~").partition("=")[0], key):
            return o
    return key
