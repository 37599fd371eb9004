"""Pre-training on the planner's demonstrations before the first environment step (the
``pretraining`` aid).

With the demonstrations in the replay buffer (`armexp.agents.demonstrations`) and the cloning term
in the actor's update (`armexp.agents.cloning`), the agent still spends its first tens of
thousands of environment steps learning what the buffer already shows: the critic has to carry
the reach reward back along the demonstrated detours before the actor can follow them. DQfD
(Hester et al., 2018) starts with a pre-training phase instead: ``gradient_steps`` of the
agent's own update on the demonstrations alone, so that interaction begins with an actor close
to the planner's and a critic that values its paths. Here those are SAC's updates (entropy,
critics, actor with its cloning term, target averaging), on batches from the buffer as the
demonstrations aid filled it. They cost compute, not environment steps: the agent has taken
none yet. Privileged: it learns from the planner's paths.
"""

from __future__ import annotations

import time

from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.agents.demonstrations import PlannerDemonstrations


class DemonstrationPretraining(TrainingAddOn):
    """``gradient_steps`` updates on the demonstrations before training (module doc), in calls
    of the preset's own ``gradient_steps`` so that a compiled update reuses the graph training
    uses. Listed after the demonstrations (and after the cloning term, for the actor to clone
    while it pre-trains). A resumed run does not pre-train again."""

    declaration = aids.PRETRAINING
    needs = (PlannerDemonstrations,)

    def __init__(self, gradient_steps: int) -> None:
        if int(gradient_steps) < 1:
            raise ValueError(f"gradient_steps={gradient_steps} must be at least 1")
        self.gradient_steps = int(gradient_steps)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        if ctx.resumed:
            return []
        import mlflow

        model = ctx.model
        assert isinstance(model, OffPolicyAlgorithm)  # its declaration says so
        per_call = max(int(model.gradient_steps), 1)
        started = time.perf_counter()
        done = 0
        while done < self.gradient_steps:
            steps = min(per_call, self.gradient_steps - done)
            model.train(gradient_steps=steps, batch_size=model.batch_size)
            done += steps
        wall = time.perf_counter() - started
        mlflow.log_metrics({"pretraining/gradient_steps": done, "pretraining/wall_s": wall})
        return []
