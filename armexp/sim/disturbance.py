"""The disturbance τ_d(t) of eq. 2 (eq. 40 for the paper's arm) at an RK4 step's start, half
step and end.

Per joint i, τ_d,i(t) = cos_amp_i cos(cos_freq_i t) + rand_amp_i u, with u ~ U(0, 1) drawn once
per controller period (`armexp.sim.noise`). The cosine at the step's start comes from the τ_d
slots of the angle cache (`armexp.sim.angle_cache`) and is rotated by freq·dt/2 and freq·dt for
the later stages.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from armexp.sim.angle_cache import turn
from armexp.sim.model import Array
from armexp.sim.noise import uniform
from armexp.sim.work import FASTMATH


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def base_dist(t: float, anchor: bool, dist: Array, slots: Array) -> None:
    """Move the τ_d slots (3 × n: φ₀, cos, sin) to the step's start."""
    for i in range(slots.shape[1]):
        if dist[0, i] != 0.0:
            phi = dist[1, i] * t
            if anchor:
                c = math.cos(phi)
                s = math.sin(phi)
            else:
                c, s = turn(phi, slots[0, i], slots[1, i], slots[2, i])
            slots[0, i] = phi
            slots[1, i] = c
            slots[2, i] = s


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def disturbance(key: np.uint64, k: int, dist: Array, rot: Array, slots: Array, ext: Array) -> None:
    """τ_d of step k at its start, half step and end into ext rows 0, 1, 2 (3 × n).

    ``rot`` holds cos, sin of freq·dt/2 and of freq·dt per joint (rows 0–3).
    """
    n = slots.shape[1]
    for i in range(n):
        noise = dist[2, i] * uniform(key, k, i, n) if dist[2, i] != 0.0 else 0.0
        amp = dist[0, i]
        if amp != 0.0:
            c = slots[1, i]
            s = slots[2, i]
            ext[0, i] = amp * c + noise
            ext[1, i] = amp * (c * rot[0, i] - s * rot[1, i]) + noise
            ext[2, i] = amp * (c * rot[2, i] - s * rot[3, i]) + noise
        else:
            ext[0, i] = noise
            ext[1, i] = noise
            ext[2, i] = noise


@njit(cache=True)
def rotations(dist: Array, dt: float, rot: Array) -> None:
    """cos, sin of freq·dt/2 and of freq·dt per joint into ``rot`` rows 0–3, for `disturbance`."""
    for i in range(dist.shape[1]):
        w = dist[1, i] * dt
        rot[0, i] = math.cos(0.5 * w)
        rot[1, i] = math.sin(0.5 * w)
        rot[2, i] = math.cos(w)
        rot[3, i] = math.sin(w)
