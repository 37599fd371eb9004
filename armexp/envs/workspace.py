"""The precomputed collision-free reachable workspace that targets are drawn from
(docs/design.md §6).

Joint space inside the limits is gridded so that one grid move per joint is exactly what the
velocity bound allows in one time cell (h_j = q̇_j,max · Δt). A breadth-first search from the
initial configuration over cells whose tip is clear of every obstacle by ``path_margin`` then gives,
for every cell, the least time in which a velocity-bounded motion that never brings the tip into
an obstacle can reach it. Targets are the tips of cells that are

* reachable within ``max_time`` (so an episode of ``max_steps`` actions has slack to get there),
* at least ``target_margin`` from every obstacle surface, and
* at least ``min_distance`` from the initial tip (else an episode would start already reached),

deduplicated on a Cartesian grid of ``resolution`` so that sampling is uniform over the area of
the workspace rather than over joint space.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from armexp.envs.geometry import Array, clearance, tips
from armexp.envs.grid_search import (
    bfs_layers,
    grid_moves,
    neighbour_offsets,
    relax_unreached,
)


@dataclass(frozen=True)
class Workspace:
    """Target points (P, 2), their least travel times (s) and a configuration reaching each."""

    points: Array
    times: Array
    configs: Array
    cell_time: float

    def __len__(self) -> int:
        return int(self.points.shape[0])

    def sample_index(self, rng: np.random.Generator) -> int:
        """The index of a point drawn uniformly."""
        return int(rng.integers(len(self)))

    def sample(self, rng: np.random.Generator) -> Array:
        return self.points[self.sample_index(rng)].copy()

    def travel_time(self, point: Array | list[float]) -> float:
        """Least travel time to the workspace point nearest ``point`` (s)."""
        d = np.linalg.norm(self.points - np.asarray(point, dtype=np.float64), axis=1)
        return float(self.times[int(np.argmin(d))])


@dataclass(frozen=True)
class JointGrid:
    """Joint space inside the limits, one time cell ``dt`` per grid move of each joint; ``free``
    marks the cells whose tip is clear of every obstacle by the path margin."""

    axes: list[Array]
    tip: Array
    free: np.ndarray
    dt: float

    def cell(self, q: Array) -> tuple[int, ...]:
        """The grid cell nearest ``q`` (clipped to the grid)."""
        return tuple(
            int(np.clip(np.rint((q[j] - a[0]) / (a[1] - a[0])), 0, len(a) - 1))
            for j, a in enumerate(self.axes)
        )


def joint_grid(
    lengths: Array,
    lower: Array,
    upper: Array,
    bound: Array,
    obstacles: Array,
    path_margin: float,
    cells: int,
) -> JointGrid:
    """About ``cells`` cells over the joint box, spaced h_j = q̇_j,max · Δt."""
    n = lengths.shape[0]
    spans = (upper - lower) / bound
    dt = float((np.prod(spans) / cells) ** (1.0 / n))
    axes = [np.arange(lower[j], upper[j] + 1e-12, bound[j] * dt) for j in range(n)]
    tip = tips(np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1), lengths)
    free: np.ndarray = np.asarray((clearance(tip, obstacles) > path_margin).all(-1))
    return JointGrid(axes, tip, free, dt)


def fill_unreached(times: Array, dt: float) -> Array:
    """``times`` with every inf replaced by the least time over paths of grid moves through
    such cells to a finite cell, ``dt`` per move (all zeros when nothing is finite). Finite
    times are kept: a path through the filled cells never shortens them."""
    if not np.isfinite(times).any():
        return np.zeros_like(times)
    t = np.pad(np.asarray(times, dtype=np.float64), 1, constant_values=np.inf)
    unreached = np.pad(~np.isfinite(times), 1, constant_values=False)
    flat = t.ravel()
    relax_unreached(flat, unreached.ravel(), neighbour_offsets(t.shape), float(dt))
    return flat.reshape(t.shape)[(slice(1, -1),) * times.ndim].copy()


def breadth_first_times(free: np.ndarray, start: np.ndarray, dt: float, layers: int) -> Array:
    """Least time (s) from the ``start`` cells to every ``free`` cell in at most ``layers`` moves
    of one cell per joint (inf beyond)."""
    padded = np.pad(free, 1, constant_values=False)
    depth = bfs_layers(
        padded.ravel(), np.pad(start, 1, constant_values=False).ravel(),
        neighbour_offsets(padded.shape), int(layers),
    ).reshape(padded.shape)[(slice(1, -1),) * free.ndim]  # fmt: skip
    return np.where(depth >= 0, depth * dt, np.inf)


def travel_times(
    lengths: Array,
    lower: Array,
    upper: Array,
    q0: Array,
    bound: Array,
    obstacles: Array,
    path_margin: float,
    max_time: float,
    cells: int,
) -> tuple[list[Array], Array, float]:
    """Grid axes, least travel time per cell (inf where unreachable) and the time cell Δt."""
    grid = joint_grid(lengths, lower, upper, bound, obstacles, path_margin, cells)
    if not (clearance(tips(q0, lengths), obstacles) > path_margin).all():
        raise ValueError(
            "the initial configuration puts the tip inside an obstacle (or within "
            f"{path_margin} m of one); move robot.q0 or the obstacles."
        )
    start = np.zeros(grid.free.shape, dtype=bool)
    start[grid.cell(q0)] = True
    free = grid.free | start  # the arm is there, whatever the grid node's rounding says
    layers = int(np.floor(max_time / grid.dt + 1e-9))
    return grid.axes, breadth_first_times(free, start, grid.dt, layers), grid.dt


def _key(a: Array) -> tuple[float, ...]:
    """A hashable cache key for an array argument."""
    return tuple(float(x) for x in np.asarray(a, dtype=np.float64).ravel())


@lru_cache(maxsize=16)
def _cached_times(key: tuple) -> tuple[list[Array], Array, float]:
    lengths, lower, upper, q0, bound, obstacles, path_margin, max_time, cells = key
    arr = [np.asarray(v, dtype=np.float64) for v in (lengths, lower, upper, q0, bound)]
    obs = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
    return travel_times(arr[0], arr[1], arr[2], arr[3], arr[4], obs, path_margin, max_time, cells)


@lru_cache(maxsize=16)
def _cached(key: tuple) -> Workspace:
    (lengths, lower, upper, q0, bound, obstacles, path_margin, target_margin, min_distance,
     max_time, cells, resolution) = key  # fmt: skip
    arr = [np.asarray(v, dtype=np.float64) for v in (lengths, lower, upper, q0, bound)]
    obs = np.asarray(obstacles, dtype=np.float64).reshape(-1, 3)
    axes, times, dt = _cached_times(
        (lengths, lower, upper, q0, bound, obstacles, path_margin, max_time, cells)
    )
    reached = np.isfinite(times)
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)[reached]
    t = times[reached]
    tip = tips(grid, arr[0])
    start_tip = tips(arr[3], arr[0])
    keep = np.linalg.norm(tip - start_tip, axis=1) >= min_distance
    if obs.shape[0]:
        keep &= (clearance(tip, obs) >= target_margin).all(-1)
    tip, t, grid = tip[keep], t[keep], grid[keep]
    if tip.shape[0] == 0:
        raise ValueError(
            "no target is reachable: every reachable tip position is too close to the start or to "
            "an obstacle; loosen env.target_margin / env.min_target_distance or move obstacles."
        )
    # One representative per Cartesian bin: the cell that reaches it soonest.
    order = np.argsort(t, kind="stable")
    keys = np.floor(tip[order] / resolution).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    pick = np.sort(order[first])
    return Workspace(points=tip[pick], times=t[pick], configs=grid[pick], cell_time=dt)


def build_workspace(
    lengths: Array,
    lower: Array,
    upper: Array,
    q0: Array,
    bound: Array,
    obstacles: Array,
    *,
    path_margin: float = 0.02,
    target_margin: float = 0.05,
    min_distance: float = 0.2,
    max_time: float = 15.0,
    cells: int = 40_000,
    resolution: float = 0.02,
) -> Workspace:
    """The workspace for one arm and obstacle set (cached: every env of a run shares it)."""

    return _cached(
        (_key(lengths), _key(lower), _key(upper), _key(q0), _key(bound), _key(obstacles),
         float(path_margin), float(target_margin), float(min_distance), float(max_time),
         int(cells), float(resolution))
    )  # fmt: skip


def shortest_path(
    lengths: Array,
    lower: Array,
    upper: Array,
    q0: Array,
    bound: Array,
    obstacles: Array,
    config: Array,
    *,
    path_margin: float = 0.02,
    max_time: float = 15.0,
    cells: int = 40_000,
) -> tuple[Array, float]:
    """A least-time grid path from ``q0`` to the grid cell ``config`` (a `Workspace.configs`
    row): the cells (K, n), one time cell apart, the first at ``q0``'s cell; and that time cell
    (s). Walks the breadth-first times of `travel_times` back down from ``config``."""

    axes, times, dt = _cached_times(
        (_key(lengths), _key(lower), _key(upper), _key(q0), _key(bound), _key(obstacles),
         float(path_margin), float(max_time), int(cells))
    )  # fmt: skip
    n = len(axes)
    step = np.array([axes[j][1] - axes[j][0] for j in range(n)])
    cell = tuple(int(np.rint((config[j] - axes[j][0]) / step[j])) for j in range(n))
    if not np.isfinite(times[cell]):
        raise ValueError(f"configuration {list(config)} is not reachable from q0 on the grid.")
    moves = grid_moves(n)
    shape = np.array(times.shape)
    path = [cell]
    while times[path[-1]] > 0:
        there = np.array(path[-1]) + moves
        inside = np.all((there >= 0) & (there < shape), axis=1)
        candidates = np.full(len(moves), np.inf)
        candidates[inside] = times[tuple(there[inside].T)]
        best = int(np.argmin(candidates))  # the first of equal times, in `grid_moves` order
        assert candidates[best] < times[path[-1]]
        path.append(tuple(int(v) for v in there[best]))
    grid = np.array([[axes[j][c[j]] for j in range(n)] for c in reversed(path)])
    return grid, dt


def time_to_go(grid: JointGrid, target: Array, threshold: float) -> Array:
    """Least time (s) from every grid cell to a cell whose tip is within ``threshold`` of
    ``target`` over the free cells (inf where none is reachable); the nearest tip's cell stands
    in when no cell is that close. Moves are symmetric, so this is a search from the goal."""
    error = np.linalg.norm(grid.tip - np.asarray(target, dtype=np.float64), axis=-1)
    goal = (error < threshold) & grid.free
    if not goal.any():
        goal = error == error[grid.free].min() if grid.free.any() else error == error.min()
    return breadth_first_times(grid.free | goal, goal, grid.dt, goal.size)
