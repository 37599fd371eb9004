"""Animations of one stored episode as GIF (Pillow) and MP4 (H.264 through the ffmpeg that
imageio-ffmpeg ships).

The input is an episode's 1 kHz trajectory with the columns of
`armexp.sim.trajectory.trajectory_columns` (``t, q_i, …, tau_i, …, tip_x, tip_y, sat_i``) and,
when present, ``target_error``. Each frame draws the arm (its links from q and the link lengths,
base at the origin), the obstacle circles, the target with its reach-threshold ring, the tip's
trace so far, and a readout of the time, the tip-to-target distance and each joint's torque
(N·m, red while at the torque limit). One frame per action period (30 ms, ≈ 33 fps); an episode
longer than ``max_frames`` periods keeps every k-th period and plays k× faster (the title says
so), and the GIF holds its last frame for a second before it loops.

Frames are drawn on one matplotlib Agg canvas: the still scene once, then per frame only the
arm, the trace and the readout over a copy of it (blitting). Nothing here imports the simulation,
environment or agent code, so a report can use it too.
"""

from __future__ import annotations

import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.font_manager import FontProperties, findfont
from matplotlib.patches import Circle
from PIL import Image, ImageDraw, ImageFont

FORMATS = ("gif", "mp4")
#: One frame per action period of the environment.
FRAME_PERIOD = 0.03
#: 12 s of episode at one frame per period; a longer episode is thinned (k× speed).
MAX_FRAMES = 400
#: Pixels per side; a multiple of 16, H.264's macro block, so ffmpeg never rescales.
SIZE = 480
#: How long the GIF shows the final state before it loops (s).
FINAL_HOLD = 1.0
#: Rows of the 1 kHz trajectory between points of the drawn tip trace.
TRACE_EVERY = 10

BACKGROUND = "#fafaf7"
OBSTACLE = "#e8a19e"
REACH = "#c8c8c8"
TARGET = "#1e9e3c"
ARM = "#34344a"
TRACE = "#1f6fb4"
TEXT = "#222222"
AT_LIMIT = "#c0392b"


@dataclass(frozen=True)
class Scene:
    """What stays still in an animation: the link lengths (m), the obstacle circles
    ``(x, y, r)`` (m), the target ``(x, y)`` and its reach threshold (m), and a title."""

    lengths: tuple[float, ...]
    circles: tuple[tuple[float, float, float], ...]
    target: tuple[float, float]
    threshold: float
    title: str = ""


def frame_rows(
    t: np.ndarray, period: float = FRAME_PERIOD, max_frames: int = MAX_FRAMES
) -> np.ndarray:
    """Row indices of the frames in a trajectory sampled at times ``t``: one row per ``period``
    seconds, every k-th of them when there are more than ``max_frames``, and always the last
    row (the final state)."""
    if len(t) == 0:
        return np.zeros(0, dtype=np.int64)
    dt = float(t[1] - t[0]) if len(t) > 1 else period
    step = max(1, round(period / dt))
    rows = np.arange(0, len(t), step)
    stride = math.ceil(len(rows) / max(1, max_frames - 1)) if len(rows) > max_frames else 1
    rows = rows[::stride]
    if rows[-1] != len(t) - 1:
        rows = np.append(rows, len(t) - 1)
    return rows


def joint_points(q: np.ndarray, lengths: Sequence[float]) -> np.ndarray:
    """Base, joint and tip positions ``(rows, n + 1, 2)`` of the arm at angles ``q`` (rows, n):
    base at the origin, each angle relative to the previous link."""
    angles = np.cumsum(np.atleast_2d(q), axis=1)
    links = np.stack([np.cos(angles), np.sin(angles)], axis=-1) * np.asarray(lengths)[:, None]
    points = np.cumsum(links, axis=1)
    return np.concatenate([np.zeros((len(points), 1, 2)), points], axis=1)


def _palette() -> Image.Image:
    """A fixed GIF palette: each drawing colour blended with the background in 24 steps (the
    anti-aliased edges), plus the arm over an obstacle. Every frame maps onto the same colours,
    so they do not flicker and unchanged pixels stay unchanged between frames."""
    bg = np.array(to_rgb(BACKGROUND))
    colors = [bg]
    for color in (OBSTACLE, REACH, TARGET, ARM, TRACE, TEXT, AT_LIMIT):
        c = np.array(to_rgb(color))
        colors += [bg + (c - bg) * k / 24 for k in range(1, 25)]
    arm, obstacle = np.array(to_rgb(ARM)), np.array(to_rgb(OBSTACLE))
    colors += [obstacle + (arm - obstacle) * k / 16 for k in range(1, 16)]
    table = np.zeros((256, 3), dtype=np.uint8)
    table[: len(colors)] = np.round(np.array(colors) * 255)
    image = Image.new("P", (1, 1))
    image.putpalette(table.ravel().tolist())
    return image


class Animator:
    """The drawing of one scene: a square Agg canvas of ``size`` pixels with the still parts
    drawn once."""

    def __init__(self, scene: Scene, n: int, size: int = SIZE) -> None:
        self.scene, self.n, self.size = scene, n, size
        fig = Figure(figsize=(size / 100, size / 100), dpi=100, facecolor=BACKGROUND)
        self.canvas = FigureCanvasAgg(fig)
        self.fig = fig
        ax = fig.add_axes((0.09, 0.12, 0.82, 0.82))
        reach = float(sum(scene.lengths))
        extent = reach * 1.06
        ax.set_xlim(-extent, extent)
        ax.set_ylim(-extent, extent)
        ax.set_aspect("equal")
        ax.set_axis_off()
        ax.add_patch(Circle((0, 0), reach, fill=False, ec=REACH, lw=1, ls="--"))
        for x, y, r in scene.circles:
            ax.add_patch(Circle((x, y), r, fc=OBSTACLE, ec="none"))
        tx, ty = scene.target
        ax.add_patch(Circle((tx, ty), scene.threshold, fill=False, ec=TARGET, lw=1.2))
        ax.plot([tx], [ty], "x", color=TARGET, ms=7, mew=2)
        ax.plot([0], [0], "s", color=ARM, ms=8)
        fig.text(0.5, 0.965, scene.title, ha="center", va="top", fontsize=10, color=TEXT)
        self.trace = ax.plot([], [], "-", color=TRACE, lw=1.4, animated=True)[0]
        self.arm = ax.plot([], [], "-o", color=ARM, lw=5, ms=6, mfc=BACKGROUND, mew=1.6,
                           solid_capstyle="round", animated=True)[0]  # fmt: skip
        self.ax = ax
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)
        # The readout changes every frame: Pillow draws it, some ten times faster than laying
        # the text out with matplotlib each frame (the same font, which matplotlib ships).
        self.font = ImageFont.truetype(findfont(FontProperties(family="DejaVu Sans")), 13)

    def frames(self, trajectory: pd.DataFrame, rows: np.ndarray) -> Iterator[np.ndarray]:
        """The RGB frames ``(size, size, 3)`` at the given rows of ``trajectory``."""
        n = self.n
        q = trajectory[[f"q_{j}" for j in range(1, n + 1)]].to_numpy()
        points = joint_points(q[rows], self.scene.lengths)
        tau = trajectory[[f"tau_{j}" for j in range(1, n + 1)]].to_numpy()[rows]
        sat_columns = [f"sat_{j}" for j in range(1, n + 1)]
        sat = (
            trajectory[sat_columns].to_numpy()[rows] > 0
            if all(c in trajectory for c in sat_columns)
            else np.zeros_like(tau, dtype=bool)
        )
        t = trajectory["t"].to_numpy()[rows]
        tip = trajectory[["tip_x", "tip_y"]].to_numpy()
        has_error = "target_error" in trajectory
        error = trajectory["target_error"].to_numpy()[rows] if has_error else None
        ink, alarm = _rgb(TEXT), _rgb(AT_LIMIT)
        column = (self.size - 24) // max(n, 1)
        for k, row in enumerate(rows):
            self.canvas.restore_region(self.background)
            trace = np.vstack([tip[: row + 1 : TRACE_EVERY], tip[row]])
            self.trace.set_data(trace[:, 0], trace[:, 1])
            self.arm.set_data(points[k, :, 0], points[k, :, 1])
            self.ax.draw_artist(self.trace)
            self.ax.draw_artist(self.arm)
            image = Image.fromarray(np.asarray(self.canvas.buffer_rgba())[..., :3])
            pen = ImageDraw.Draw(image)
            clock = f"t = {t[k]:5.2f} s"
            if error is not None:
                clock += f"      tip to target {100 * error[k]:5.1f} cm"
            pen.text((12, self.size - 42), clock, font=self.font, fill=ink)
            for j in range(n):
                value = f"{tau[k, j]:+7.1f}".replace("-", "−")
                pen.text((12 + j * column, self.size - 22), f"τ{j + 1} = {value} N·m",
                              font=self.font, fill=alarm if sat[k, j] else ink)  # fmt: skip
            yield np.asarray(image)


def _rgb(color: str) -> tuple[int, int, int]:
    r, g, b = (round(255 * c) for c in to_rgb(color))
    return r, g, b


class _Gif:
    """Frames mapped onto the fixed palette, saved by Pillow when closed."""

    def __init__(self, path: Path, period: float) -> None:
        self.path, self.period = path, period
        self.palette = _palette()
        self.frames: list[Image.Image] = []

    def add(self, frame: np.ndarray) -> None:
        image = Image.fromarray(frame).quantize(palette=self.palette, dither=Image.Dither.NONE)
        self.frames.append(image)

    def close(self) -> None:
        if not self.frames:  # a failed drawing leaves no file rather than an empty one
            return
        ms = round(self.period * 1000)
        durations = [ms] * len(self.frames)
        durations[-1] = max(ms, round(FINAL_HOLD * 1000))
        first, *rest = self.frames
        first.save(self.path, save_all=True, append_images=rest, duration=durations, loop=0)


class _Mp4:
    """Frames piped to ffmpeg (H.264, yuv420p, which browsers play)."""

    def __init__(self, path: Path, period: float, size: int) -> None:
        import imageio_ffmpeg

        fps = 1 / Fraction(period).limit_denominator(1000)
        self.writer = imageio_ffmpeg.write_frames(
            str(path), (size, size), fps=fps, codec="libx264", quality=6,
            ffmpeg_log_level="error",
            output_params=["-preset", "veryfast", "-movflags", "+faststart"],
        )  # fmt: skip
        self.writer.send(None)

    def add(self, frame: np.ndarray) -> None:
        self.writer.send(frame)

    def close(self) -> None:
        self.writer.close()


def write(
    trajectory: pd.DataFrame,
    scene: Scene,
    stem: Path,
    formats: Sequence[str] = FORMATS,
    period: float = FRAME_PERIOD,
    max_frames: int = MAX_FRAMES,
    size: int = SIZE,
) -> dict[str, Path]:
    """Animate ``trajectory`` in ``scene`` into ``<stem>.<format>`` for each of ``formats``
    (``gif``, ``mp4``), drawing each frame once for all of them; returns the files by format."""
    unknown = sorted(set(formats) - set(FORMATS))
    if unknown:
        raise ValueError(f"formats {unknown} are not animation formats: choose from {FORMATS}")
    n = sum(1 for c in trajectory.columns if c.startswith("q_") and not c.startswith("q_d_"))
    t = trajectory["t"].to_numpy()
    rows = frame_rows(t, period, max_frames)
    if len(rows) == 0:
        raise ValueError("the trajectory has no rows to animate")
    step = max(1, round(period / float(t[1] - t[0]))) if len(t) > 1 else 1
    speed = max(1, int(rows[1] - rows[0]) // step) if len(rows) > 2 else 1
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = {fmt: stem.with_name(f"{stem.name}.{fmt}") for fmt in dict.fromkeys(formats)}
    sinks: list[_Gif | _Mp4] = [
        _Gif(path, period) if fmt == "gif" else _Mp4(path, period, size)
        for fmt, path in paths.items()
    ]
    try:
        if speed > 1:
            scene = replace(scene, title=f"{scene.title}  ({speed}× speed)")
        for frame in Animator(scene, n, size).frames(trajectory, rows):
            for sink in sinks:
                sink.add(frame)
    finally:
        for sink in sinks:
            sink.close()
    return paths
