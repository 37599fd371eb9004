"""Counter-based uniform draws for τ_d's u ~ U(0, 1) (eq. 40).

u for (seed, controller step k, joint j) is a SplitMix64 hash of those three numbers. A run's draws
therefore depend on its seed alone, not on how the simulation is chunked (30-step environment
calls, one long call, or a batch of candidates on several threads), which is what makes "same seed
⇒ identical trajectory" hold everywhere the core is used.
"""

from __future__ import annotations

import numpy as np
from numba import njit

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
_S30 = np.uint64(30)
_S27 = np.uint64(27)
_S31 = np.uint64(31)
_S11 = np.uint64(11)
_INV53 = 1.0 / 9007199254740992.0  # 2**-53


@njit(cache=True, inline="always")
def _mix(z: np.uint64) -> np.uint64:
    z = (z ^ (z >> _S30)) * _MIX1
    z = (z ^ (z >> _S27)) * _MIX2
    return z ^ (z >> _S31)


@njit(cache=True)
def stream_key(seed: int) -> np.uint64:
    """A well-mixed 64-bit key for a user seed (any int ≥ 0)."""
    return _mix(np.uint64(seed) * _GOLDEN + _GOLDEN)


@njit(cache=True, inline="always")
def uniform(key: np.uint64, step: int, joint: int, n: int) -> float:
    """u ∈ [0, 1) for controller step ``step`` and ``joint`` of an n-joint arm."""
    z = _mix(key + np.uint64(step * n + joint + 1) * _GOLDEN)
    return float(z >> _S11) * _INV53


def uniform_numpy(seed: int, steps: np.ndarray, n: int) -> np.ndarray:
    """Plain-numpy twin of `uniform` for the reference simulator: shape (len(steps), n)."""
    with np.errstate(over="ignore"):
        key = _mix_np(np.uint64(seed) * _GOLDEN + _GOLDEN)
        idx = steps.astype(np.uint64)[:, None] * np.uint64(n) + np.arange(n, dtype=np.uint64)
        z = _mix_np(key + (idx + np.uint64(1)) * _GOLDEN)
    return (z >> _S11).astype(np.float64) * _INV53


def _mix_np(z: np.ndarray | np.uint64) -> np.ndarray:
    x: np.ndarray = np.asarray(z, dtype=np.uint64)
    x = (x ^ (x >> _S30)) * _MIX1
    x = (x ^ (x >> _S27)) * _MIX2
    return np.asarray(x ^ (x >> _S31), dtype=np.uint64)
