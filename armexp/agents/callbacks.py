"""SB3 callbacks and logger output that stream training to MLflow and keep it resumable."""

from __future__ import annotations

import json
import tempfile
import time
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from mlflow.entities import Metric
from mlflow.tracking import MlflowClient
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.logger import KVWriter

from armexp.agents import kept_buffer
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.console import progress_bar
from armexp.tracking.artifacts import log_batch, log_folder

#: Artifact paths of a train run.
CHECKPOINT_DIR = "checkpoint"
MODEL_DIR = "model"
MODEL_FILE = "model.zip"
STATE_FILE = "state.json"


class MLflowOutputFormat(KVWriter):
    """SB3 logger output that sends every numeric value SB3 records (train/actor_loss,
    rollout/ep_rew_mean, rollout/success_rate, …) to the active MLflow run, at SB3's step."""

    def __init__(self, run_id: str) -> None:
        self.run_id = run_id
        self.client = MlflowClient()

    def write(
        self,
        key_values: dict[str, Any],
        key_excluded: dict[str, tuple[str, ...]],
        step: int = 0,
    ) -> None:
        now = int(time.time() * 1000)
        metrics = [
            Metric(key, float(value), now, step)
            for key, value in sorted(key_values.items())
            if "mlflow" not in (key_excluded.get(key) or ())
            and isinstance(value, int | float | np.floating | np.integer)
            and not isinstance(value, bool)
            and np.isfinite(value)
        ]
        log_batch(self.run_id, metrics, client=self.client)

    def close(self) -> None:
        pass


class EpisodeStats(BaseCallback):
    """Per-episode reward, length, success and collision, plus rates over the last ``window``
    episodes, logged in batches every ``log_every`` environment steps (and at the end)."""

    def __init__(self, run_id: str, log_every: int, window: int = 100, start_episode: int = 0):
        super().__init__()
        self.run_id = run_id
        self.log_every = log_every
        self.recent: deque[tuple[bool, bool]] = deque(maxlen=window)
        self.episodes = start_episode
        self.pending: list[Metric] = []
        self.client = MlflowClient()
        self.started = time.perf_counter()
        self.wall_offset = 0.0
        self._last_flush = 0

    @property
    def success_rate(self) -> float:
        return float(np.mean([s for s, _ in self.recent])) if self.recent else 0.0

    @property
    def collision_rate(self) -> float:
        return float(np.mean([c for _, c in self.recent])) if self.recent else 0.0

    def wall(self) -> float:
        return self.wall_offset + time.perf_counter() - self.started

    def _on_step(self) -> bool:
        clock = int(time.time() * 1000)
        step = self.num_timesteps
        ended = 0
        for info in self.locals["infos"]:
            episode = info.get("episode")
            if episode is None:
                continue
            # MLflow keeps one row per (key, timestamp, step, value): episodes of parallel
            # environments that end on the same step get their own millisecond.
            now = clock + ended
            ended += 1
            self.episodes += 1
            success, collision = bool(info.get("is_success")), bool(info.get("collision"))
            self.recent.append((success, collision))
            self.pending += [
                Metric("episode/reward", float(episode["r"]), now, step),
                Metric("episode/length", float(episode["l"]), now, step),
                Metric("episode/success", float(success), now, step),
                Metric("episode/collision", float(collision), now, step),
                Metric("rollout/success_rate_100", self.success_rate, now, step),
                Metric("rollout/collision_rate_100", self.collision_rate, now, step),
                Metric("rollout/episodes", float(self.episodes), now, step),
                Metric("time/wall_s", self.wall(), now, step),
            ]
        if step - self._last_flush >= self.log_every:
            self.flush()
        return True

    def flush(self) -> None:
        self._last_flush = self.num_timesteps
        batch, self.pending = self.pending, []
        log_batch(self.run_id, batch, client=self.client)

    def _on_training_end(self) -> None:
        self.flush()


class Checkpoint(BaseCallback):
    """Every ``every`` environment steps: the model (policy, critics, optimisers, entropy
    coefficient and step count; no replay buffer, which an interruption's `save` adds) and a
    small state file, logged over the previous checkpoint's artifacts so that an interrupted
    run can be resumed."""

    def __init__(self, every: int, state: Callable[[], dict[str, Any]]):
        super().__init__()
        self.every = every
        self.state = state
        self._last = 0

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last >= self.every:
            self.save()
        return True

    def save(self, folder: str = CHECKPOINT_DIR, with_buffer: bool = False) -> None:
        """``with_buffer``: the replay buffer too (`armexp.agents.kept_buffer`), as on an
        interruption."""
        self._last = self.num_timesteps
        log_model(self.model, folder, self.state(), with_buffer)


def log_model(model: Any, folder: str, state: dict[str, Any], with_buffer: bool = False) -> None:
    """The model and its state file as the artifacts ``folder/`` (`MODEL_FILE`, `STATE_FILE`;
    with ``with_buffer`` the replay buffer, `kept_buffer.BUFFER_FILE`, and the state says so),
    each written under a temporary name and renamed when complete (`log_folder`), in sorted
    order: the state last, so a write that fails leaves the previous state, which does not
    claim a buffer it was not written with."""
    with tempfile.TemporaryDirectory() as tmp:
        model.save(str(Path(tmp) / MODEL_FILE))
        if with_buffer and kept_buffer.save(model, Path(tmp)):
            state = {**state, kept_buffer.STATE_KEY: True}
        (Path(tmp) / STATE_FILE).write_text(json.dumps(state, indent=1))
        log_folder(tmp, folder)


class Progress(BaseCallback):
    """A tqdm bar over environment steps showing the recent success and collision rates."""

    def __init__(self, total: int, stats: EpisodeStats, initial: int = 0) -> None:
        super().__init__()
        self.total = total
        self.stats = stats
        self.initial = initial
        self.bar: Any = None

    def _on_training_start(self) -> None:
        self.bar = progress_bar(True, self.total, "train", "step", initial=self.initial)

    def _on_step(self) -> bool:
        if self.bar is not None and self.n_calls % 200 == 0:
            self.bar.n = self.num_timesteps
            self.bar.set_postfix(
                episodes=self.stats.episodes,
                success=f"{self.stats.success_rate:.2f}",
                collision=f"{self.stats.collision_rate:.2f}",
                refresh=True,
            )
        return True

    def _on_training_end(self) -> None:
        if self.bar is not None:
            self.bar.n = self.num_timesteps
            self.bar.close()


class PaceLine(BaseCallback):
    """Without a progress bar (logs, captured output): a line every ``every_s`` seconds of
    training with the steps done, the pace over the last ``window`` lines (since this process
    started, for the first ones) and the ETA of the step budget at that pace (or of the time
    budget, when that ends first). A recent pace, not the run's average: a preset's late phase
    (more updates per step) or a busier machine would otherwise leave the ETA short for hours."""

    def __init__(
        self,
        total: int,
        stats: EpisodeStats,
        seconds: float | None,
        every_s: float = 60.0,
        window: int = 5,
    ) -> None:
        super().__init__()
        self.total = total
        self.stats = stats
        self.seconds = seconds
        self.every_s = every_s
        self.lines: list[str] = []
        #: (wall seconds, steps) at each of the last ``window`` lines, or at the start and the
        #: lines so far; the pace is measured from the oldest.
        self.marks: deque[tuple[float, int]] = deque(maxlen=window)

    def _on_training_start(self) -> None:
        wall = self.stats.wall()
        self.marks.append((wall, self.num_timesteps))
        self.next_at = wall + self.every_s

    def _on_step(self) -> bool:
        if self.n_calls % 100 == 0:
            wall = self.stats.wall()
            if wall >= self.next_at:
                self.say(wall)
        return True

    def say(self, wall: float) -> None:
        self.next_at = wall + self.every_s
        since_wall, since_step = self.marks[0]
        pace = (self.num_timesteps - since_step) / max(wall - since_wall, 1e-9)
        self.marks.append((wall, self.num_timesteps))
        eta = max(self.total - self.num_timesteps, 0) / pace if pace > 0 else float("inf")
        if self.seconds is not None:
            eta = min(eta, max(self.seconds - wall, 0.0))
        line = (
            f"train: {self.num_timesteps:,} of {self.total:,} steps | {pace:,.0f} steps/s | "
            f"ETA {eta / 60:.1f} min | success (last 100) {self.stats.success_rate:.2f}"
        )
        self.lines.append(line)
        print(line, flush=True)


class Budget(BaseCallback):
    """Stops training after ``episodes`` episodes, ``steps`` environment steps or ``seconds`` of
    wall time, whichever comes first (None: no limit)."""

    def __init__(
        self, stats: EpisodeStats, episodes: int, steps: int | None, seconds: float | None
    ) -> None:
        super().__init__()
        self.stats = stats
        self.episodes = episodes
        self.steps = steps
        self.seconds = seconds
        self.reason = ""

    def _on_step(self) -> bool:
        if self.stats.episodes >= self.episodes:
            self.reason = "episodes"
        elif self.steps is not None and self.num_timesteps >= self.steps:
            self.reason = "steps"
        elif self.seconds is not None and self.stats.wall() >= self.seconds:
            self.reason = "time"
        return not self.reason

    def used(self, num_timesteps: int) -> float:
        """The share of the budget spent (0 to 1): the furthest of episodes, steps and time."""
        shares = [self.stats.episodes / self.episodes]
        if self.steps:
            shares.append(num_timesteps / self.steps)
        if self.seconds:
            shares.append(self.stats.wall() / self.seconds)
        return min(max(shares), 1.0)


class HeldOutEval(BaseCallback):
    """Every ``every`` environment steps, and once more at the end of training when the last
    check came before it, the deterministic policy on fixed held-out targets: logs
    ``eval/success_rate``, ``eval/collision_rate`` and ``eval/mean_return`` against the step,
    with ``eval/wall_s`` the training wall time so far. The time spent here is taken off the
    training clock, so a wall-time budget counts training only."""

    def __init__(
        self, run_id: str, every: int, env: Any, targets: list[np.ndarray], stats: EpisodeStats
    ) -> None:
        super().__init__()
        self.run_id = run_id
        self.every = every
        self.env = env
        self.targets = targets
        self.stats = stats
        self.client = MlflowClient()
        self._last = 0
        self.history: list[dict[str, float]] = []

    def _on_step(self) -> bool:
        if self.num_timesteps - self._last >= self.every:
            self.evaluate()
        return True

    def _on_training_end(self) -> None:
        # The policy as trained is what a budget buys: an HPO trial is scored on this check.
        if self.num_timesteps > self._last:
            self.evaluate()

    def evaluate(self) -> dict[str, float]:
        from armexp.agents.rollout import rollout

        self._last = self.num_timesteps
        started = time.perf_counter()
        reasons, returns = [], []
        for i, target in enumerate(self.targets):
            episode = rollout(self.env, self.model, {"target": target}, seed=i)
            reasons.append(episode.reason)
            returns.append(episode.episode_return)
        self.stats.wall_offset -= time.perf_counter() - started
        point = {
            "eval/success_rate": float(np.mean([r == "reached" for r in reasons])),
            "eval/collision_rate": float(np.mean([r == "collision" for r in reasons])),
            "eval/mean_return": float(np.mean(returns)),
            "eval/wall_s": self.stats.wall(),
        }
        self.history.append({"step": float(self.num_timesteps), **point})
        now = int(time.time() * 1000)
        metrics = [Metric(k, v, now, self.num_timesteps) for k, v in point.items()]
        log_batch(self.run_id, metrics, client=self.client)
        return point


class HeldOutChecks(TrainingAddOn):
    """The `HeldOutEval` callback as a ``train.callbacks`` entry: every ``every`` environment
    steps (0: never) the deterministic policy on ``targets`` workspace targets drawn with
    ``seed`` (apart from `armexp eval`'s ``tasks.random_seed``). The callback is shared with
    later add-ons as ``ctx.shared[SHARED]`` (an HPO trial's pruning reads its checks); the last
    check's success rate is the run's ``final/held_out_success``."""

    SHARED = "held_out"

    def __init__(self, every: int, targets: int = 50, seed: int = 10_007) -> None:
        if int(every) < 0 or int(targets) < 1:
            raise ValueError(f"every={every} must be ≥ 0 and targets={targets} at least 1")
        self.every, self.targets, self.seed = int(every), int(targets), int(seed)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        if not self.every:
            return []
        from armexp.envs.reach import ReachEnv

        probe = ReachEnv(ctx.settings)
        rng = np.random.default_rng(self.seed)
        targets = [probe.workspace.sample(rng) for _ in range(self.targets)]
        check = HeldOutEval(ctx.run_id, self.every, probe, targets, ctx.stats)
        ctx.shared[self.SHARED] = check
        return [check]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        check = ctx.shared.get(self.SHARED)
        if not isinstance(check, HeldOutEval) or not check.history:
            return {}
        return {"final/held_out_success": check.history[-1]["eval/success_rate"]}
