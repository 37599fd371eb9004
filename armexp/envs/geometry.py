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
    """Whether the straight segment p0→p1 enters any obstacle.

    The tip moves ≤ ~2 cm in one 30 ms action, so its 1 kHz path is a segment to within a
    fraction of a millimetre; checking the segment rather than its end points means a tip that
    clips an obstacle between two actions still counts as a collision.
    """
    if obstacles.shape[0] == 0:
        return False
    c = obstacles[:, :2]
    seg = p1 - p0
    length2 = float(seg @ seg)
    s = np.clip(((c - p0) @ seg) / length2, 0.0, 1.0) if length2 > 0 else np.zeros(c.shape[0])
    nearest = p0 + s[:, None] * seg
    return bool((((c - nearest) ** 2).sum(1) < obstacles[:, 2] ** 2).any())
