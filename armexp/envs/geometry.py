"""Planar geometry of the reaching task: forward kinematics and circular tip obstacles.

Obstacles are circles ``(x, y, r)`` in the arm's plane (base at the origin, y up). Only the tip
may not enter them (the paper's end-effector collision avoidance).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def tips(q: Array, lengths: Array) -> Array:
    """Tip positions (..., 2) for joint angles q (..., n)."""
    th = np.cumsum(q, axis=-1)
    return np.stack([(lengths * np.cos(th)).sum(-1), (lengths * np.sin(th)).sum(-1)], axis=-1)


def joint_positions(q: Array, lengths: Array) -> Array:
    """Base, every joint and the tip of one configuration: shape (n + 1, 2)."""
    th = np.cumsum(q)
    steps = np.stack([lengths * np.cos(th), lengths * np.sin(th)], axis=1)
    return np.vstack([np.zeros((1, 2)), np.cumsum(steps, axis=0)])


def clearance(points: Array, obstacles: Array) -> Array:
    """Distance from each point (..., 2) to each obstacle's surface (..., m); < 0 inside."""
    if obstacles.shape[0] == 0:
        return np.zeros((*points.shape[:-1], 0))
    d = points[..., None, :] - obstacles[:, :2]
    return np.sqrt((d**2).sum(-1)) - obstacles[:, 2]


def segment_hits(p0: Array, p1: Array, obstacles: Array) -> bool:
    """Whether the straight segment p0→p1 enters any obstacle (the environment's collision test,
    `armexp.envs.kernel.segment_enters`, which checks the tip's path over each 30 ms action)."""
    from armexp.envs.kernel import segment_enters

    obs = np.ascontiguousarray(obstacles, dtype=np.float64).reshape(-1, 3)
    return bool(segment_enters(float(p0[0]), float(p0[1]), float(p1[0]), float(p1[1]), obs))
