"""The model classes behind ``agent.algo``: each library algorithm with armexp's resume refill.

A checkpoint keeps the model without its replay buffer (`armexp.agents.callbacks.Checkpoint`), so
an off-policy run that resumes starts with an empty buffer. The library would refill it with
uniform random actions until ``learning_starts``; `ResumeRefill` refills it with the policy it
resumes instead (`armexp.stages.train` moves ``learning_starts`` past the resumed step count).
SAC's class, which also changes the update, is `armexp.agents.sac.ResumableSAC`.

PPO resumes without a class of its own: it is on-policy, so a checkpoint loses at most the
rollout being collected, which the resumed run collects afresh with the same policy.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from sb3_contrib import TQC, CrossQ
from stable_baselines3 import TD3
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm


class ResumeRefill(OffPolicyAlgorithm):
    """Once ``resumed``, the actions before ``learning_starts`` are the policy's (with the
    algorithm's exploration), not uniform random ones."""

    resumed = False

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.resumed:
            learning_starts = 0
        return super()._sample_action(learning_starts, action_noise, n_envs)


class ResumableTD3(ResumeRefill, TD3):
    """SB3's TD3 with `ResumeRefill`."""


class ResumableTQC(ResumeRefill, TQC):
    """sb3-contrib's TQC with `ResumeRefill`."""


class ResumableCrossQ(ResumeRefill, CrossQ):
    """sb3-contrib's CrossQ with `ResumeRefill`."""
