"""The checked arguments of a cuckoo search (`armexp.tune.cuckoo`): each bad one is named in a
one-sentence ValueError, in the order the search takes them."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NoReturn

import numpy as np
from numpy.typing import ArrayLike, NDArray

#: The abandonment rules of phase 2 (docs/design.md §5).
ABANDON_RULES = ("worst", "per_component")

FloatArray = NDArray[np.float64]


def fail(message: str) -> NoReturn:
    raise ValueError(message)


def as_bounds(name: str, value: ArrayLike) -> FloatArray:
    try:
        arr = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(
            f"{name}={value!r} is not a sequence of numbers; give one number per dimension."
        ) from None
    if arr.ndim != 1:
        fail(
            f"{name} has shape {arr.shape}; it must be a 1-D sequence with one number "
            "per dimension."
        )
    if arr.size == 0:
        fail(f"{name}={value!r} is empty; give at least one bound.")
    bad = np.flatnonzero(~np.isfinite(arr))
    if bad.size:
        i = int(bad[0])
        fail(f"{name}[{i}]={float(arr[i])!r} is not finite; every bound must be a finite number.")
    return arr


def as_real(name: str, value: object) -> float:
    if isinstance(value, bool):
        fail(f"{name}={value!r} is not a number.")
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ValueError(f"{name}={value!r} is not a number.") from None


def as_int(name: str, value: object, minimum: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int | np.integer):
        fail(f"{name}={value!r} is not an integer; it must be an integer >= {minimum}.")
    result = int(value)
    if result < minimum:
        fail(f"{name}={result} is too small; it must be an integer >= {minimum}.")
    return result


def mantegna_sigma(beta: float) -> float:
    num = math.gamma(1.0 + beta) * math.sin(math.pi * beta / 2.0)
    den = math.gamma((1.0 + beta) / 2.0) * beta * 2.0 ** ((beta - 1.0) / 2.0)
    # At beta == 2 the sine is ~1e-16 (possibly of either sign in other libms); the Lévy step
    # then vanishes, which is the documented degenerate limit rather than an error.
    return float(max(num / den, 0.0) ** (1.0 / beta))


def n_abandoned(n_nests: int, pa: float) -> int:
    """Nests discarded per iteration by the ``"worst"`` rule: ``pa * n_nests`` rounded half up,
    capped at ``n_nests - 1`` so the best nest always survives."""
    return min(math.floor(pa * n_nests + 0.5), n_nests - 1)


@dataclass(frozen=True)
class Settings:
    """The checked arguments of one run."""

    lo: FloatArray
    hi: FloatArray
    #: Nests, iterations, and nests evaluated in each abandonment phase.
    n: int
    n_iter: int
    n_worst: int
    pa: float
    beta: float
    scale: float
    abandon: str
    #: Mantegna's sigma_u for ``beta``.
    sigma_u: float

    @property
    def d(self) -> int:
        return int(self.lo.size)


def check_arguments(
    lower: ArrayLike,
    upper: ArrayLike,
    n_nests: int,
    n_iterations: int,
    pa: float,
    beta: float,
    step_scale: float,
    abandon: str,
) -> Settings:
    """The arguments checked in order, the first bad one named in a one-sentence ValueError."""
    lo = as_bounds("lower", lower)
    hi = as_bounds("upper", upper)
    if lo.shape != hi.shape:
        fail(
            f"lower has {lo.size} entries but upper has {hi.size}; they must have the same "
            "length, one per dimension."
        )
    not_below = np.flatnonzero(lo >= hi)
    if not_below.size:
        i = int(not_below[0])
        relation = "equal to" if lo[i] == hi[i] else "greater than"
        fail(
            f"lower[{i}]={float(lo[i])!r} is {relation} upper[{i}]={float(hi[i])!r}; "
            "every lower bound must be strictly below its upper bound."
        )
    n = as_int("n_nests", n_nests, 2)
    n_iter = as_int("n_iterations", n_iterations, 0)
    pa_f = as_real("pa", pa)
    if not 0.0 <= pa_f <= 1.0:
        fail(f"pa={pa_f!r} is outside [0, 1]; it is a probability.")
    beta_f = as_real("beta", beta)
    if not 0.0 < beta_f <= 2.0:
        fail(f"beta={beta_f!r} is outside (0, 2]; the Lévy exponent must satisfy 0 < beta <= 2.")
    scale = as_real("step_scale", step_scale)
    if not (scale > 0.0 and math.isfinite(scale)):
        fail(f"step_scale={scale!r} is not allowed; it must be a finite number above 0.")
    if not isinstance(abandon, str) or abandon not in ABANDON_RULES:
        fail(
            f"abandon={abandon!r} is not a known rule; it must be one of "
            f"{', '.join(ABANDON_RULES)}."
        )
    n_worst = n_abandoned(n, pa_f) if abandon == "worst" else n
    return Settings(lo, hi, n, n_iter, n_worst, pa_f, beta_f, scale, abandon,
                     mantegna_sigma(beta_f))  # fmt: skip
