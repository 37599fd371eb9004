"""Pruning an HPO trial on the held-out checks while it trains (`armexp hpo` only: Hydra's
sweeper runs jobs that never see the trial).

A trial trains its seeds one after the other; the check of seed ``i`` (0-based, in the order of
``hpo.seeds``) at environment step ``t`` is reported as step ``i · budget + t``, so the pruner
compares every trial's same seed at the same step.
"""

from __future__ import annotations

from typing import Any

from stable_baselines3.common.callbacks import BaseCallback

from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.agents.callbacks import HeldOutChecks, HeldOutEval


class ReportChecks(TrainingAddOn):
    """Reports each held-out check's success rate to ``trial`` at ``offset`` + its step, and
    stops the training when the trial's pruner says so (``pruned_at``: the step it stopped)."""

    def __init__(self, trial: Any, offset: int) -> None:
        self.trial, self.offset = trial, int(offset)
        self.pruned_at: int | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        check = ctx.shared.get(HeldOutChecks.SHARED)
        return [_Reporter(self, check)] if isinstance(check, HeldOutEval) else []


class _Reporter(BaseCallback):
    def __init__(self, addon: ReportChecks, check: HeldOutEval) -> None:
        super().__init__()
        self.addon, self.check, self.seen = addon, check, 0

    def _report(self) -> None:
        history = self.check.history
        while self.seen < len(history):
            point = history[self.seen]
            self.seen += 1
            self.addon.trial.report(
                float(point["eval/success_rate"]), self.addon.offset + int(point["step"])
            )

    def _on_step(self) -> bool:
        if self.seen == len(self.check.history):
            return True
        self._report()
        if self.addon.trial.should_prune():
            self.addon.pruned_at = self.addon.offset + int(self.check.history[-1]["step"])
            return False  # SB3 ends training; the run finishes with what it learned
        return True

    def _on_training_end(self) -> None:
        self._report()  # the final check (`HeldOutEval` runs it before this callback)
