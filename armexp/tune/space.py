"""The space cuckoo search moves in: the parameters that act, on a log scale (docs/design.md §5).

Gains that span decades (a PID's kp from 10² to 10⁶, the adaptive rates from 10⁻⁶ to 10²) are
searched as log10 of their value, so a Lévy flight or a random walk moves them by factors, not by
amounts that are huge for a small gain and tiny for a large one. ``log=False`` searches the
values themselves.

The adaptive law's closed loop depends on b1, c1, r1 only through λ = c1·r1 and γ = b1²·c1
(`armexp.sim.controllers`), so its search coordinates are (a0, a1, λ, γ) and each point maps to
the gains [a0, a1, √(γ/λ), λ, 1]. The PID and the computed-torque law are searched over their own
gains (kp_1 … kd_n).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from armexp.sim.controllers import (
    ADAPTIVE,
    ADAPTIVE_SEARCH_NAMES,
    adaptive_from_rates,
    adaptive_rates,
    gain_names,
)
from armexp.sim.model import Array

#: A coordinate within this share of the box's width (in the search's own scale) from a bound
#: counts as on it.
ON_BOUND = 1e-3


def coordinate_names(kind: int, n: int) -> list[str]:
    """The search coordinates of a controller: a0, a1, lambda, gamma (adaptive), or its gains."""
    return list(ADAPTIVE_SEARCH_NAMES) if kind == ADAPTIVE else gain_names(kind, n)


@dataclass(frozen=True)
class SearchSpace:
    """A box over a controller's search coordinates, in natural units, searched in log10 of
    them when ``log``."""

    kind: int
    names: tuple[str, ...]
    lower: Array
    upper: Array
    log: bool = True

    def __post_init__(self) -> None:
        lower = np.asarray(self.lower, float)
        upper = np.asarray(self.upper, float)
        for name, lo, hi in zip(self.names, lower, upper, strict=True):
            if self.log and not lo > 0:
                raise ValueError(
                    f"controller.bounds.{name}=[{lo:g}, {hi:g}] is not allowed: the search is in "
                    "log space (tuner.log_space=true), so both bounds must be > 0."
                )
            if not lo < hi:
                raise ValueError(
                    f"controller.bounds.{name}=[{lo:g}, {hi:g}] is not allowed: the lower bound "
                    "must be below the upper bound."
                )

    @property
    def search_lower(self) -> Array:
        return self._scale(np.asarray(self.lower, float))

    @property
    def search_upper(self) -> Array:
        return self._scale(np.asarray(self.upper, float))

    def _scale(self, values: Array) -> Array:
        return np.log10(values) if self.log else np.asarray(values, float)

    def values(self, x: Array) -> Array:
        """Search points (K, d) → coordinates in natural units (K, d)."""
        x = np.atleast_2d(np.asarray(x, float))
        return np.power(10.0, x) if self.log else x

    def gains(self, x: Array) -> Array:
        """Search points (K, d) → the controller's gain vectors (K, p)."""
        v = self.values(x)
        if self.kind == ADAPTIVE:
            return adaptive_from_rates(v[:, 0], v[:, 1], v[:, 2], v[:, 3])
        return v

    def coordinates(self, gains: Array) -> Array:
        """A gain vector (p,) → its coordinates in natural units (d,)."""
        g = np.asarray(gains, float)
        if self.kind == ADAPTIVE:
            lam, gamma = adaptive_rates(g)
            return np.array([g[0], g[1], lam, gamma])
        return g

    def point(self, gains: Array) -> Array:
        """A gain vector (p,) → its search point (d,) (log10 of its coordinates with ``log``),
        each coordinate clipped to the box first (a gain of 0 has no logarithm)."""
        return self._scale(np.clip(self.coordinates(gains), self.lower, self.upper))

    def on_bound(self, gains: Array) -> list[str]:
        """The coordinates of ``gains`` within `ON_BOUND` of the box's width (in the search's
        scale) from a bound, as ``name=lower|upper``."""
        point = self._scale(self.coordinates(gains))
        lo, hi = self.search_lower, self.search_upper
        tol = ON_BOUND * (hi - lo)
        out = []
        for name, v, a, b, t in zip(self.names, point, lo, hi, tol, strict=True):
            if v - a <= t:
                out.append(f"{name}=lower")
            elif b - v <= t:
                out.append(f"{name}=upper")
        return out

    def objective(self, score: Callable[[Array], Array]) -> Callable[[Array], Array]:
        """``score`` of gain vectors as a function of search points."""

        def of_points(x: Array) -> Array:
            return score(self.gains(x))

        return of_points
