"""The learning aids' declarations: for each aid, its name in ``agent.aids`` (as the presets spell
it), the add-on class its ``_target_`` names, whether it uses privileged knowledge, its short name
for captions, its Table II text and the ``agent.algo`` values it applies to.

This is the one place that says so. The add-on classes (`armexp.agents.addons.TrainingAddOn`)
point at their declaration (``declaration``), and the report reads the declarations to name a
stored run's aids; the report runs without the agent code (torch, SB3), so the declarations are
plain data here rather than attributes the report would have to import the classes to read.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from armexp.config.agent_schema import ALGORITHMS

#: Every ``agent.algo``, and those that learn from a replay buffer.
ALL_ALGORITHMS = frozenset(ALGORITHMS)
OFF_POLICY = frozenset({"sac", "td3", "tqc", "crossq"})


def number_arg(args: Mapping[str, Any], key: str) -> float:
    """Argument ``key`` of a stored aid config as a number (0 when missing or not a number):
    the report describes old runs too, whatever they logged."""
    try:
        value = float(args.get(key))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return 0.0
    return value if math.isfinite(value) else 0.0


@dataclass(frozen=True)
class AidDeclaration:
    """One learning aid, as training composes it and the report names it."""

    #: Its name in ``agent.aids``.
    name: str
    #: The ``_target_`` of its add-on class.
    target: str
    #: Uses privileged knowledge (the planner, the obstacles): a run with it is aided.
    privileged: bool
    #: Its short name in the report's captions.
    title: str
    #: What it does with its arguments (its config, as a run logged it), for Table II.
    describe: Callable[[Mapping[str, Any]], str]
    #: The ``agent.algo`` values it applies to; another is refused before a run starts
    #: (`armexp.config.check_aid`).
    algorithms: frozenset[str] = ALL_ALGORITHMS
    #: What in the ``agent`` config it cannot work with: None, or that key, its value and what
    #: to give instead (one phrase), checked before a run starts.
    conflicts: Callable[[Mapping[str, Any]], str | None] = lambda agent: None


def listed_as(agent: Mapping[str, Any], aid: AidDeclaration) -> list[str]:
    """The keys of ``agent.aids`` that hold ``aid``: under its own name, or under any key with
    its ``_target_``."""
    return [
        key
        for key, spec in (agent.get("aids") or {}).items()
        if key == aid.name or (isinstance(spec, Mapping) and spec.get("_target_") == aid.target)
    ]


DEMONSTRATIONS = AidDeclaration(
    "demonstrations", "armexp.agents.demonstrations.PlannerDemonstrations", True,
    "demonstrations",
    lambda a: f"{int(number_arg(a, 'episodes'))} planner demonstrations in the replay buffer",
    OFF_POLICY,  # PPO has no replay buffer
)  # fmt: skip
CLONING = AidDeclaration(
    "cloning", "armexp.agents.cloning.BehaviourCloning", True, "behaviour cloning",
    lambda a: f"behaviour cloning of the demonstrations (weight {number_arg(a, 'weight'):g})",
    frozenset({"sac"}),  # a term of SAC's own actor update (armexp.agents.sac)
)  # fmt: skip
EXPERT = AidDeclaration(
    "expert", "armexp.agents.expert.DaggerExpert", True, "DAgger expert",
    lambda a: "DAgger: the planner's action cloned on every visited state",
    frozenset({"sac"}),  # it adds to what the cloning aid clones
)  # fmt: skip
PRETRAINING = AidDeclaration(
    "pretraining", "armexp.agents.pretraining.DemonstrationPretraining", True, "pre-training",
    lambda a: (
        f"{int(number_arg(a, 'gradient_steps'))} gradient steps on the demonstrations before the "
        "first environment step"
    ),
    OFF_POLICY,  # it trains on the replay buffer the demonstrations filled
)  # fmt: skip
AVERAGING = AidDeclaration(
    "averaging", "armexp.agents.averaging.WeightAveraging", False, "weight averaging",
    lambda a: (
        f"final actor averaged over the last {number_arg(a, 'tail') * 100:g} % of the budget"
    ),
    OFF_POLICY,  # a separate actor; PPO's shares one module with its value network
)  # fmt: skip
CURRICULUM = AidDeclaration(
    "curriculum", "armexp.agents.curriculum.TargetCurriculum", False, "target curriculum",
    lambda a: (
        f"targets within {number_arg(a, 'start'):g} m of the starting tip, widened to the whole "
        f"workspace by {number_arg(a, 'full_at') * 100:g} % of the budget"
    ),
)  # fmt: skip
HER = AidDeclaration(
    "her", "armexp.agents.relabel.GoalRelabelling", False, "goal relabelling (HER)",
    lambda a: (
        f"hindsight goal relabelling: {number_arg(a, 'ratio') * 100:g} % of each batch toward a "
        "tip reached later in the episode, rewarded by the environment's own function"
    ),
    OFF_POLICY,  # it relabels a replay buffer
    lambda agent: (
        None if int(agent.get("n_steps", 1)) == 1 else
        f"agent.n_steps={agent.get('n_steps')}: HER relabels one-step rewards (an n-step "
        "buffer's sums were taken toward the old target); set agent.n_steps=1"
    ),
)  # fmt: skip
MISSED_TARGETS = AidDeclaration(
    "missed_targets", "armexp.agents.curriculum.MissedTargets", False, "missed-target curriculum",
    lambda a: (
        f"{number_arg(a, 'share') * 100:g} % of training targets re-drawn among the last "
        f"{int(number_arg(a, 'memory'))} the policy missed, per environment"
    ),
)  # fmt: skip
RANDOM_STARTS = AidDeclaration(
    "random_starts", "armexp.agents.curriculum.RandomStarts", False, "random starts",
    lambda a: (
        f"{number_arg(a, 'share') * 100:g} % of training episodes started at a workspace "
        "point's posture drawn uniformly instead of the fixed start"
    ),
)  # fmt: skip
COLOURED_NOISE = AidDeclaration(
    "coloured_noise", "armexp.agents.exploration.ColouredNoise", False,
    "coloured-noise exploration",
    lambda a: (
        f"rollout actions sampled with coloured noise (exponent {number_arg(a, 'beta'):g}) instead "
        "of white"
    ),
    frozenset({"sac", "tqc", "crossq"}),  # a squashed-Gaussian actor whose samples it colours
)  # fmt: skip

SELF_IMITATION = AidDeclaration(
    "self_imitation", "armexp.agents.self_imitation.SelfImitation", False, "self-imitation",
    lambda a: (
        f"self-imitation of the agent's own reaching episodes where their return beat the critic "
        f"(weight {number_arg(a, 'weight'):g}, last {int(number_arg(a, 'capacity'))} steps)"
    ),
    frozenset({"sac"}),  # a term of SAC's own actor update (armexp.agents.sac)
)  # fmt: skip
COUNT_BONUS = AidDeclaration(
    "count_bonus", "armexp.agents.novelty.CountBonus", False, "count bonus",
    lambda a: (
        f"an exploration bonus {number_arg(a, 'beta'):g}/√N over posture cells of "
        f"{number_arg(a, 'cell'):g} rad added to the stored rewards, falling to 0 at "
        f"{number_arg(a, 'until') * 100:g} % of the budget"
    ),
    OFF_POLICY,  # it adds to the rewards a replay buffer stores
    lambda agent: next((
        f"agent.aids.{key}: HER recomputes the rewards of the samples it relabels with the "
        "environment's own function, so they would lose the bonus and the rest keep it; "
        f"remove one of the two (~agent.aids.{key} or ~agent.aids.count_bonus)"
        for key in listed_as(agent, HER)
    ), None),
)  # fmt: skip

LIMIT_GUARD = AidDeclaration(
    "limit_guard", "armexp.agents.limit_guard.LimitGuard", False, "joint-limit guard",
    lambda a: (
        f"actions cut to keep the joint reference {number_arg(a, 'margin'):g} rad inside the "
        "joint limits, in training and evaluation"
    ),
)  # fmt: skip


def _late_phase_text(a: Mapping[str, Any]) -> str:
    changes = [
        *([f"γ {number_arg(a, 'gamma'):g}"] if a.get("gamma") is not None else []),
        *([f"{int(number_arg(a, 'gradient_steps'))} gradient steps per call"]
          if a.get("gradient_steps") is not None else []),
    ]  # fmt: skip
    return f"from {number_arg(a, 'at') * 100:g} % of the budget on, {' and '.join(changes)}"


LATE_PHASE = AidDeclaration(
    "late_phase", "armexp.agents.late_phase.LatePhase", False, "late phase",
    _late_phase_text,
    OFF_POLICY,  # it sets the discount of a replay buffer's samples and the updates per call
    lambda agent: next((
        f"agent.aids.{key}: self-imitation takes its returns at the discount training starts "
        f"with, and the late phase changes it; remove one of the two (~agent.aids.{key} or "
        "~agent.aids.late_phase)"
        for key in listed_as(agent, SELF_IMITATION)
    ), None),
)  # fmt: skip

#: Every aid, in the order the presets list them.
AIDS = (DEMONSTRATIONS, CLONING, PRETRAINING, EXPERT, AVERAGING, CURRICULUM, MISSED_TARGETS,
        RANDOM_STARTS, HER, COLOURED_NOISE, SELF_IMITATION, COUNT_BONUS,
        LIMIT_GUARD, LATE_PHASE)  # fmt: skip


#: The guard's margin when its config gives none (rad): above the tracking error of the tuned
#: controllers at the joint speed bounds, small beside the reach threshold's 0.04 m.
DEFAULT_GUARD_MARGIN = 0.02


def limit_guard_margin(agent: Mapping[str, Any] | None) -> float | None:
    """The margin (rad) of the ``limit_guard`` aid in an ``agent`` config (found by its
    ``_target_``, under any key), or None without it: the guard acts in the environment
    (`armexp.envs.limit_guard`), so every environment built for the policy (training, its
    held-out checks, evaluation, replay) reads it from the policy's config."""
    for aid in ((agent or {}).get("aids") or {}).values():
        if isinstance(aid, Mapping) and aid.get("_target_") == LIMIT_GUARD.target:
            return float(aid.get("margin", DEFAULT_GUARD_MARGIN))
    return None


def declared(target: str) -> AidDeclaration | None:
    """The declaration of ``target``, an add-on's ``_target_`` or an aid's name; None for any
    other."""
    return next((a for a in AIDS if target in (a.target, a.name)), None)


def privileged_modules() -> tuple[str, ...]:
    """The modules of the aids that use privileged knowledge: anything else of theirs that a
    config composes (another add-on, a callback) uses that knowledge too."""
    return tuple(dict.fromkeys(a.target.rpartition(".")[0] for a in AIDS if a.privileged))
