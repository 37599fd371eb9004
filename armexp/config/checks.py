"""Value checks attached to structured-config fields, and the one-sentence error they raise."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import field
from typing import Any


class ConfigError(ValueError):
    """A user-facing configuration mistake: its message is one sentence naming key and value."""


class Check:
    """A predicate on a field's value with a human description of what is allowed."""

    def __init__(self, ok: Callable[[Any], bool], allowed: str) -> None:
        self.ok = ok
        self.allowed = allowed

    def __call__(self, value: Any) -> bool:
        try:
            return bool(self.ok(value))
        except (TypeError, ValueError):
            return False


def _num(x: Any) -> bool:
    """A finite number (a gain, a budget or a length of inf says nothing usable)."""
    return isinstance(x, int | float) and not isinstance(x, bool) and math.isfinite(x)


def positive() -> Check:
    return Check(lambda v: _num(v) and v > 0, "it must be a number > 0")


def nonnegative() -> Check:
    return Check(lambda v: _num(v) and v >= 0, "it must be a number ≥ 0")


def between(lo: float, hi: float, *, lo_open: bool = False) -> Check:
    left = "(" if lo_open else "["
    return Check(
        lambda v: _num(v) and (lo < v if lo_open else lo <= v) and v <= hi,
        f"it must lie in {left}{lo}, {hi}]",
    )


def at_least(lo: float) -> Check:
    return Check(lambda v: _num(v) and v >= lo, f"it must be ≥ {lo}")


def matches(pattern: str, allowed: str) -> Check:
    """A string that matches ``pattern`` in full."""
    import re

    return Check(lambda v: isinstance(v, str) and re.fullmatch(pattern, v) is not None, allowed)


def one_of(*choices: str) -> Check:
    return Check(lambda v: v in choices, "allowed: " + ", ".join(choices))


def each(check: Check, *, nonempty: bool = True) -> Check:
    def ok(v: Any) -> bool:
        return (not nonempty or len(v) > 0) and all(check(x) for x in v)

    return Check(ok, f"every entry must satisfy: {check.allowed}")


def or_null(check: Check) -> Check:
    """``check``, or the value left unset (None)."""
    return Check(lambda v: v is None or check(v), f"{check.allowed}, or null")


def checked(default: Any = None, check: Check | None = None, *, factory: Any = None) -> Any:
    """A dataclass field with a value check (``metadata['check']``)."""
    meta = {"check": check} if check is not None else {}
    if factory is not None:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


def fail(key: str, value: Any, allowed: str) -> ConfigError:
    return ConfigError(f"{key}={_show(value)} is not allowed: {allowed}.")


def _show(value: Any) -> str:
    if isinstance(value, Sequence) and not isinstance(value, str):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    return repr(value) if isinstance(value, str) else str(value)
