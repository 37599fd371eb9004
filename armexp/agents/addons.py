"""Learning aids: training add-ons that `armexp train` composes from ``agent.aids``.

``agent.aids`` maps a name to a config with a ``_target_`` (Hydra instantiation), in the order
they apply, as ``callbacks:`` lists do in lightning-hydra-template::

    aids:
      demonstrations: {_target_: armexp.agents.demonstrations.PlannerDemonstrations, episodes: 1000}
      cloning: {_target_: armexp.agents.cloning.BehaviourCloning, weight: 3.0}

Each aid gets the model and the environment's settings before training (`TrainingAddOn.setup`,
which may return SB3 callbacks) and may change the model after it (`TrainingAddOn.finish`,
which returns ``final/*`` metrics). Each aid points at its declaration in `armexp.aids`, which
says whether it uses the planner's or the obstacles' knowledge and so makes a run *aided*
(docs/design.md §7); the report says so for every table built from one.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, ClassVar

from stable_baselines3.common.callbacks import BaseCallback

from armexp.aids import ALL_ALGORITHMS, AidDeclaration
from armexp.config import ConfigError, check_aid
from armexp.envs.reach import ReachSettings

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm


@dataclass
class TrainingContext:
    """What the aids of one training run share."""

    #: The model of ``agent.algo`` (`armexp.agents.factory`); an aid may rely on what its
    #: ``algorithms`` guarantee (a replay buffer, SAC's actor terms).
    model: BaseAlgorithm
    settings: ReachSettings
    seed: int
    #: True when the run continues from a checkpoint (its replay buffer is the interrupted
    #: run's, `armexp.agents.kept_buffer`, or empty after a process killed outright).
    resumed: bool
    #: The share of the training budget spent so far (0 to 1).
    budget_used: Callable[[], float]
    #: Training wall time so far (s); `stats` keeps it.
    wall: Callable[[], float]
    #: The train run, and the per-episode statistics that stream to it.
    run_id: str = ""
    stats: Any = None
    #: Set by the demonstrations aid: how many planner episodes to plan.
    demo_episodes: int = 0
    #: What the aids hand each other, by the aid module that owns it (typed there, so that
    #: this module imports none of them): ``armexp.agents.cloning`` puts its
    #: ``DemonstrationCloning`` here for aids that add to what it clones;
    #: ``armexp.agents.demonstrations.planned`` keeps the planned episodes here.
    shared: dict[str, Any] = field(default_factory=dict)


class TrainingAddOn:
    """One add-on to an agent's training (see the module doc)."""

    #: Its declaration (`armexp.aids`): its name, whether it uses privileged knowledge (the
    #: planner, the obstacles: the run is aided), and how the report names it. None: an add-on
    #: the report names by its ``_target_``.
    declaration: ClassVar[AidDeclaration | None] = None
    #: Aids that must come before this one in ``agent.aids`` (by class).
    needs: ClassVar[tuple[type[TrainingAddOn], ...]] = ()
    #: The ``agent.algo`` values it applies to (a declared aid's, from its declaration);
    #: another is refused before a run starts (`armexp.config.check_aid`).
    algorithms: ClassVar[frozenset[str]] = ALL_ALGORITHMS

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.declaration is not None and "algorithms" not in cls.__dict__:
            cls.algorithms = cls.declaration.algorithms

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        """Before training: change the model or the context; the callbacks to run."""
        return []

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        """After training, before the final model is saved; metrics to log."""
        return {}


def build_addons(
    specs: Mapping[str, Any], where: str = "agent.aids", algo: str | None = None
) -> list[TrainingAddOn]:
    """The add-ons of ``specs`` (the config at ``where``), in order, for ``agent.algo=algo``
    (None: not checked); a bad entry is one `ConfigError` sentence naming its key."""
    from hydra.utils import instantiate

    aids: list[TrainingAddOn] = []
    for name, spec in specs.items():
        key = f"{where}.{name}"
        try:
            aid = instantiate(spec)
        except Exception as exc:
            cause = exc.__cause__ or exc
            raise ConfigError(
                f"{key} is not allowed: it could not be built ({cause}); give a _target_ that "
                "names a training add-on (armexp.agents.addons.TrainingAddOn) and its arguments."
            ) from None
        if not isinstance(aid, TrainingAddOn):
            raise ConfigError(
                f"{key}._target_={spec.get('_target_')} is not allowed: it is not a training "
                "add-on (armexp.agents.addons.TrainingAddOn)."
            )
        if algo is not None:
            check_aid(key, type(aid).__name__, aid.algorithms, algo)
        for need in aid.needs:
            if not any(isinstance(a, need) for a in aids):
                raise ConfigError(
                    f"{key} is not allowed without a {need.__name__} listed before it in {where}."
                )
        aids.append(aid)
    return aids
