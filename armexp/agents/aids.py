"""The learning aids by name: each aid's name in ``agent.aids`` (as the presets spell it) and the
add-on class its ``_target_`` names.

The classes declare the rest (`armexp.agents.addons.TrainingAddOn`: ``privileged``, ``title``,
``describe``); the report reads a stored run's aids through this module, so that it names them
as the add-ons do. The classes are imported when first asked for: they bring in torch and SB3,
which a report that shows no aided run does not need.
"""

from __future__ import annotations

import importlib
from functools import cache
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from armexp.agents.addons import TrainingAddOn

#: Name in ``agent.aids`` → the ``_target_`` of the add-on.
TARGETS = {
    "demonstrations": "armexp.agents.demonstrations.PlannerDemonstrations",
    "cloning": "armexp.agents.cloning.BehaviourCloning",
    "expert": "armexp.agents.expert.DaggerExpert",
    "averaging": "armexp.agents.averaging.WeightAveraging",
}


@cache
def addon_class(target: str) -> type[TrainingAddOn] | None:
    """The add-on class of ``target``, a ``_target_`` of `TARGETS` or a name in it; None for
    any other (the report never imports what a stored run names)."""
    from armexp.agents.addons import TrainingAddOn

    path = TARGETS.get(target, target)
    if path not in TARGETS.values():
        return None
    module, _, name = path.rpartition(".")
    found = getattr(importlib.import_module(module), name)
    assert isinstance(found, type) and issubclass(found, TrainingAddOn), path
    return found


def privileged_modules() -> tuple[str, ...]:
    """The modules of the aids that use privileged knowledge: anything else of theirs that a
    config composes (another add-on, a callback) uses that knowledge too."""
    modules = []
    for target in TARGETS.values():
        found = addon_class(target)
        if found is not None and found.privileged:
            modules.append(target.rpartition(".")[0])
    return tuple(dict.fromkeys(modules))
