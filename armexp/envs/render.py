"""A tiny numpy rasteriser for ``render_mode="rgb_array"`` (no display, no GUI toolkit)."""

from __future__ import annotations

import numpy as np

Color = tuple[int, int, int]
Point = tuple[float, float]


class Canvas:
    """A square RGB image over the world box [−extent, extent]² (y up)."""

    def __init__(self, extent: float, size: int = 400) -> None:
        self.size = size
        self.scale = size / (2.0 * extent)
        self.extent = extent
        centres = (np.arange(size) + 0.5) / self.scale - extent
        self._x = centres[None, :]
        self._y = centres[::-1, None]
        self._img = np.empty((size, size, 3), dtype=np.uint8)

    def clear(self, color: Color = (250, 250, 247)) -> None:
        self._img[:] = color

    def _paint(self, mask: np.ndarray, color: Color) -> None:
        self._img[mask] = color

    def disc(self, centre: Point, radius: float, color: Color) -> None:
        d2 = (self._x - centre[0]) ** 2 + (self._y - centre[1]) ** 2
        self._paint(d2 <= radius**2, color)

    def ring(self, centre: Point, radius: float, color: Color, width: float = 0.008) -> None:
        d = np.sqrt((self._x - centre[0]) ** 2 + (self._y - centre[1]) ** 2)
        self._paint(np.abs(d - radius) <= width, color)

    def segment(self, p0: Point, p1: Point, half_width: float, color: Color) -> None:
        vx, vy = p1[0] - p0[0], p1[1] - p0[1]
        length2 = vx * vx + vy * vy
        wx, wy = self._x - p0[0], self._y - p0[1]
        s = np.clip((wx * vx + wy * vy) / length2, 0.0, 1.0) if length2 > 0 else 0.0
        d2 = (wx - s * vx) ** 2 + (wy - s * vy) ** 2
        self._paint(d2 <= half_width**2, color)

    def image(self) -> np.ndarray:
        return self._img.copy()
