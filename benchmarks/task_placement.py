"""Where tasks (a)–(d) lie: distance from the initial tip, least travel time, line of sight.

Run from the repository root (extra arguments are Hydra overrides of the packaged config)::

    python benchmarks/task_placement.py                  # the configured tasks
    python benchmarks/task_placement.py --search         # placements like the paper's, 5 cm grid
    python benchmarks/task_placement.py obstacles=none

For each task: the Euclidean distance from the initial tip, the least travel time of the
environment's workspace (``env.path_margin`` kept from every obstacle, velocity bounds, joint
limits; `armexp.envs.workspace`), the straight-line joint-space time (the same search with no
obstacles) and the line of sight: the clearance of the straight tip segment from the start to
the target to the nearest obstacle surface (< 0: it enters that obstacle; ``blocked`` when it
enters an obstacle grown by the path margin).

``--search`` looks on a grid for four targets placed as the paper describes its tasks (§V,
Table III): (d) the second farthest from the start yet reached soonest, in clear sight; (a), (b)
and (c) behind obstacles (the segment enters an obstacle by ``--inside`` or more); least times
ordered d < a <= b < c and as close as possible to 5.5, 9.2, 9.9 and 11.2 s.
"""

from __future__ import annotations

import argparse
import itertools
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import Array, clearance, tips
from armexp.envs.reach import ReachSettings
from armexp.envs.workspace import Workspace, build_workspace

#: Table III's target times (s).
PAPER_TIMES = {"a": 9.176, "b": 9.92, "c": 11.16, "d": 5.456}


def sight(start: Array, target: Array, obstacles: Array) -> tuple[float, int]:
    """Least distance from the segment start→target to an obstacle surface (< 0 inside), and
    that obstacle's index (-1 without obstacles)."""
    if obstacles.shape[0] == 0:
        return float("inf"), -1
    seg = target - start
    t = np.clip(((obstacles[:, :2] - start) @ seg) / max(float(seg @ seg), 1e-12), 0.0, 1.0)
    nearest = start + t[:, None] * seg
    gaps = np.linalg.norm(obstacles[:, :2] - nearest, axis=1) - obstacles[:, 2]
    i = int(np.argmin(gaps))
    return float(gaps[i]), i


def free_workspace(s: ReachSettings) -> Workspace:
    """The workspace of the same arm without obstacles: straight-line joint-space times."""
    return build_workspace(
        s.plant.arm.lengths_array, s.joint_lower, s.joint_upper, s.q0, s.velocity_bound,
        np.zeros((0, 3)), min_distance=0.0, max_time=60.0, cells=s.workspace_cells,
    )  # fmt: skip


def describe(s: ReachSettings, ws: Workspace, free: Workspace, p: Array) -> dict[str, float]:
    start = tips(s.q0, s.plant.arm.lengths_array)
    gap, obstacle = sight(start, p, s.obstacles)
    nearest = int(np.argmin(np.linalg.norm(ws.points - p, axis=1)))
    q = ws.configs[nearest]
    return {
        "distance": float(np.linalg.norm(p - start)),
        "time": ws.travel_time(p),
        "straight": free.travel_time(p),
        "sight": gap,
        "obstacle": obstacle,
        # The workspace holds the target to its bin size (its nearest point is that close).
        "off": float(np.linalg.norm(ws.points[nearest] - p)),
        # How far the configuration that reaches it soonest is from the joint limits (rad).
        "limit": float(min((q - s.joint_lower).min(), (s.joint_upper - q).min())),
        "clearance": float(clearance(p, s.obstacles).min(initial=np.inf)),
    }


def table(s: ReachSettings, ws: Workspace, free: Workspace, targets: dict[str, Array]) -> None:
    print("task      x      y  distance  time (s)  straight (s)  limit (rad)  sight (m)  "
          "line of sight")  # fmt: skip
    for name, p in sorted(targets.items()):
        r = describe(s, ws, free, p)
        blocked = r["sight"] < s.path_margin
        what = f"blocked by obstacle {r['obstacle']}" if blocked else "clear"
        print(f"({name})  {p[0]:5.2f}  {p[1]:5.2f}  {r['distance']:8.3f}  {r['time']:8.2f}  "
              f"{r['straight']:12.2f}  {r['limit']:11.2f}  {r['sight']:9.3f}  {what}")  # fmt: skip


def search(s: ReachSettings, ws: Workspace, free: Workspace, args: argparse.Namespace) -> None:
    lo, hi = np.floor(ws.points.min(0) / args.step), np.ceil(ws.points.max(0) / args.step)
    xs, ys = (np.round(np.arange(lo[j], hi[j] + 1) * args.step, 3) for j in range(2))
    cands = []
    for x, y in itertools.product(xs, ys):
        p = np.array([x, y])
        r = describe(s, ws, free, p)
        valid = r["off"] <= 0.012 and r["clearance"] >= s.target_margin
        if valid and r["limit"] >= args.limit:
            cands.append((p, r))
    print(f"{len(cands)} valid grid targets")
    roles = {}
    for name, want in PAPER_TIMES.items():
        roles[name] = [
            (p, r)
            for p, r in cands
            if abs(r["time"] - want) <= args.slack
            and (r["sight"] > s.path_margin + 0.02 if name == "d" else r["sight"] < -args.inside)
        ]
        print(f"({name}): {len(roles[name])} candidates within {args.slack} s of {want} s")
    best = []
    for combo in itertools.product(*(roles[n] for n in "abcd")):
        t = [r["time"] for _, r in combo]
        if not t[3] < t[0] <= t[1] < t[2]:
            continue
        dist = np.array([r["distance"] for _, r in combo])
        order = np.argsort(dist)
        if order[2] != 3:  # (d) second farthest
            continue
        gap = float(np.diff(np.sort(dist)).min())
        pts = np.array([p for p, _ in combo])
        apart = min(np.linalg.norm(pts[i] - pts[j]) for i, j in itertools.combinations(range(4), 2))
        if gap < args.gap or apart < args.apart:
            continue
        err = sum(abs(r["time"] - PAPER_TIMES[n]) for n, (_, r) in zip("abcd", combo, strict=True))
        best.append((err - 0.5 * gap, combo))
    best.sort(key=lambda b: b[0])
    for score, combo in best[: args.top]:
        print(f"\nscore {score:.2f}")
        table(s, ws, free, {n: p for n, (p, _) in zip("abcd", combo, strict=True)})


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("overrides", nargs="*", help="Hydra overrides, e.g. obstacles=none")
    parser.add_argument("--search", action="store_true", help="search placements like the paper")
    parser.add_argument("--step", type=float, default=0.05, help="search grid (m)")
    parser.add_argument("--slack", type=float, default=0.35, help="time off the paper's (s)")
    parser.add_argument("--inside", type=float, default=0.01, help="depth of a blocked sight (m)")
    parser.add_argument("--limit", type=float, default=0.1, help="least joint-limit margin (rad)")
    parser.add_argument("--gap", type=float, default=0.1, help="least distance gap (m)")
    parser.add_argument("--apart", type=float, default=0.3, help="least target spacing (m)")
    parser.add_argument("--top", type=int, default=5)
    args = parser.parse_args()
    s = settings_from_config(compose_config(args.overrides))
    ws, free = s.workspace(), free_workspace(s)
    start = tips(s.q0, s.plant.arm.lengths_array)
    print(f"initial tip ({start[0]:.2f}, {start[1]:.2f}); path margin {s.path_margin} m; "
          f"{len(ws)} workspace targets within {s.max_target_time} s")  # fmt: skip
    if args.search:
        search(s, ws, free, args)
    else:
        table(s, ws, free, {k: np.asarray(v, dtype=np.float64) for k, v in s.tasks.items()})
    return 0


if __name__ == "__main__":
    sys.exit(main())
