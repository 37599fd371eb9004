"""Compiled searches over the joint grid (`armexp.envs.workspace`): least grid-move counts by
breadth-first search, and the relaxation that fills the cells a search did not reach.

Both visit each cell's 3ⁿ − 1 neighbours (at most one cell per joint). The grid comes padded
with one cell of nothing on every side (not free, no time) and flattened in C order, so that a
neighbour is the cell's index plus a fixed offset. The planner's expert (`armexp.agents.expert`)
runs both once per target during training.
"""

from __future__ import annotations

import numpy as np
from numba import njit


def grid_moves(n: int) -> np.ndarray:
    """The 3ⁿ grid moves of at most one cell per joint (the zero move included)."""
    return np.stack(np.meshgrid(*[[-1, 0, 1]] * n, indexing="ij"), axis=-1).reshape(-1, n)


def neighbour_offsets(padded_shape: tuple[int, ...]) -> np.ndarray:
    """Flat index offsets of the 3ⁿ − 1 neighbours on a C-ordered grid of ``padded_shape``."""
    moves = grid_moves(len(padded_shape))
    moves = moves[np.abs(moves).sum(axis=1) > 0]
    strides = np.cumprod((*padded_shape[1:], 1)[::-1])[::-1]
    return (moves @ strides).astype(np.int64)


@njit(cache=True)
def bfs_layers(free: np.ndarray, start: np.ndarray, offsets: np.ndarray, layers: int) -> np.ndarray:
    """Grid moves from the nearest ``start`` cell to every ``free`` cell (flat, padded boolean
    arrays) within ``layers`` moves; −1 beyond. Start cells are at 0 whether free or not."""
    count = free.shape[0]
    depth = np.full(count, -1, dtype=np.int64)
    queue = np.empty(count, dtype=np.int64)
    tail = 0
    for cell in range(count):
        if start[cell]:
            depth[cell] = 0
            queue[tail] = cell
            tail += 1
    head = 0
    while head < tail:
        cell = queue[head]
        head += 1
        if depth[cell] >= layers:
            continue
        for offset in offsets:
            other = cell + offset
            if free[other] and depth[other] < 0:
                depth[other] = depth[cell] + 1
                queue[tail] = other
                tail += 1
    return depth


@njit(cache=True)
def relax_unreached(
    times: np.ndarray, unreached: np.ndarray, offsets: np.ndarray, dt: float
) -> None:
    """In place: every ``unreached`` cell of the flat, padded ``times`` (inf there and in the
    padding) gets the least time over paths of grid moves through unreached cells to a finite
    one, ``dt`` per move; sweeps until nothing changes, other cells are kept."""
    changed = True
    while changed:
        changed = False
        for cell in range(times.shape[0]):
            if not unreached[cell]:
                continue
            best = times[cell]
            for offset in offsets:
                candidate = times[cell + offset] + dt
                if candidate < best:
                    best = candidate
            if best < times[cell]:
                times[cell] = best
                changed = True
