"""Episode animations (armexp.render.animation): real GIF and MP4 files, decoded back."""

from __future__ import annotations

import math
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pandas as pd
import pytest
from PIL import GifImagePlugin, Image

from armexp.render import animation
from armexp.render.animation import Scene, frame_rows, write
from tests.helpers import run_without

CIRCLES = ((0.5, 1.3, 0.12), (1.4, 0.3, 0.12))
SCENE = Scene((1.0, 0.8), CIRCLES, (0.30, 1.55), 0.04, "test")


def _swing(seconds: float, limit_from: float = math.inf) -> pd.DataFrame:
    """A 1 kHz two-link trajectory: q1 turns from 0 to π/2 at a constant rate with the forearm
    straight (q2 = 0); joint 2's torque is at its limit from ``limit_from`` s on."""
    t = np.arange(0.0, seconds, 1e-3)
    q1, q2 = np.pi / 2 * t / t[-1], np.zeros_like(t)
    zero = np.zeros_like(t)
    sat2 = (t >= limit_from).astype(float)
    cols = {"t": t, "q_1": q1, "q_2": q2, "q_d_1": q1, "q_d_2": q2, "dq_1": zero, "dq_2": zero,
            "dq_d_1": zero, "dq_d_2": zero, "tau_1": 100 * np.cos(t), "tau_2": 250 * sat2,
            "rho_hat": zero, "tip_x": 1.8 * np.cos(q1), "tip_y": 1.8 * np.sin(q1),
            "sat_1": zero, "sat_2": sat2}  # fmt: skip
    frame = pd.DataFrame(cols)
    frame["target_error"] = np.hypot(frame.tip_x - 0.30, frame.tip_y - 1.55)
    return frame


def _arm_pixels(frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows and columns of the pixels in the arm's colour, between the title and the readout."""
    arm = np.array([int(animation.ARM[i : i + 2], 16) for i in (1, 3, 5)])
    near = np.abs(frame[40:420].astype(int) - arm).sum(axis=-1) < 30
    rows, cols = np.nonzero(near)
    return rows + 40, cols


def test_one_frame_per_action_period_capped_with_the_last_state_kept() -> None:
    t = np.arange(0.0, 9.0, 1e-3)
    rows = frame_rows(t)
    assert len(rows) == 301 and rows[1] == 30 and rows[-1] == len(t) - 1
    long = np.arange(0.0, 30.0, 1e-3)
    thinned = frame_rows(long, max_frames=400)
    assert len(thinned) <= 400 and thinned[-1] == len(long) - 1
    assert set(np.diff(thinned[:-1])) == {90}  # every third period: 3x speed


@pytest.mark.long
def test_gif_and_mp4_show_the_arm_moving_at_33_fps(tmp_path: Path) -> None:
    trajectory = _swing(3.0)
    paths = write(trajectory, SCENE, tmp_path / "swing")
    assert sorted(paths) == ["gif", "mp4"]
    expected = len(frame_rows(trajectory.t.to_numpy()))
    with Image.open(paths["gif"]) as gif:
        assert isinstance(gif, GifImagePlugin.GifImageFile)
        assert gif.n_frames == expected == 101
        assert gif.size == (480, 480) and gif.info["loop"] == 0
        assert gif.info["duration"] == 30  # one action period per frame
    frames = iio.imread(paths["gif"], index=None)
    assert frames.shape == (expected, 480, 480, 3)
    # The arm starts along +x (a horizontal band of pixels) and ends along +y (a vertical one).
    rows0, cols0 = _arm_pixels(frames[0])
    rows1, cols1 = _arm_pixels(frames[-1])
    assert rows0.std() < 5 and np.ptp(cols0) > 150
    assert cols1.std() < 5 and np.ptp(rows1) > 150
    assert cols0.mean() > cols1.mean() + 60 and rows1.mean() < rows0.mean() - 60
    assert (frames[0] != frames[50]).any() and (frames[50] != frames[-1]).any()
    video = iio.imread(paths["mp4"], plugin="FFMPEG")
    meta = iio.immeta(paths["mp4"], plugin="FFMPEG")
    assert video.shape == (expected, 480, 480, 3)
    assert meta["codec"] == "h264" and meta["fps"] == pytest.approx(100 / 3, abs=0.01)
    assert meta["pix_fmt"].startswith("yuv420p")
    # Lossy, but the same picture: the arm where the GIF has it.
    rows, cols = _arm_pixels(video[-1])
    assert abs(cols.mean() - cols1.mean()) < 8 and abs(rows.mean() - rows1.mean()) < 8


def test_the_torque_readout_turns_red_at_the_limit(tmp_path: Path) -> None:
    paths = write(_swing(1.0, limit_from=0.5), SCENE, tmp_path / "limit", formats=["gif"])
    frames = iio.imread(paths["gif"], index=None)
    red = np.array([int(animation.AT_LIMIT[i : i + 2], 16) for i in (1, 3, 5)])

    def red_pixels(frame: np.ndarray) -> int:
        return int((np.abs(frame[440:].astype(int) - red).sum(axis=-1) < 40).sum())

    assert red_pixels(frames[0]) == 0 and red_pixels(frames[-1]) > 50


def test_an_unknown_format_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="avi"):
        write(_swing(0.1), SCENE, tmp_path / "x", formats=["avi"])


def test_the_renderer_needs_no_simulation_environment_or_agent_code(tmp_path: Path) -> None:
    blocked = ["armexp.sim", "armexp.envs", "armexp.agents", "stable_baselines3", "gymnasium",
               "torch", "numba"]  # fmt: skip
    res = run_without(blocked, "import armexp.render.animation\n")
    assert res.returncode == 0, res.stderr[-2000:]
