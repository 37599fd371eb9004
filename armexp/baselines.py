"""The baselines a comparison runs, and the labels of every controller an eval runs
(docs/design.md §4 "Baselines, tuned as carefully as the method", §8).

The one owner of the names: ``eval.baselines`` takes keys of `BASELINES`, and the labels below
are the ``controller`` column of ``episodes.csv``, the first part of eval metric names
(``<label>.<task>.<metric>``) and the keys of an eval run's ``controllers.yaml``:

* the policy's own controller: ``adaptive`` (subsystem_adaptive), else the controller's name;
* ``adaptive_off``: the ablation, the policy's adaptive law with adaptation off (b1 = 0, ρ̂ ≡ 0);
* each baseline by its name (`BASELINES`);
* ``adaptive_<criterion>``: the adaptive law tuned under a baseline's criterion where that differs
  from the policy's gains' criterion: the proposed side of that baseline's comparison.

Pure data and rules: no config, tracking or simulation imports (the config schema reads it).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

ADAPTIVE = "subsystem_adaptive"
#: Roles of the labels (``controllers.yaml``'s ``role``).
PROPOSED, ABLATION, BASELINE, REFERENCE = "proposed", "ablation", "baseline", "reference"
ROLES = (PROPOSED, ABLATION, BASELINE, REFERENCE)
#: The ablation's label.
ADAPTIVE_OFF = "adaptive_off"
#: The criterion recorded for gains taken from the config rather than from a tune run.
CONFIG = "config"


@dataclass(frozen=True)
class Baseline:
    """A baseline: the controller it runs and the criterion it is tuned under (None: the
    comparison's, ``tuner.objective.criterion`` of the eval's config)."""

    controller: str
    criterion: str | None
    description: str


BASELINES: dict[str, Baseline] = {
    "pid_gaing": Baseline(
        "pid", "gaing", "joint PID tuned on the paper's objective W (Gaing), the paper's baseline"
    ),
    "pid_itae": Baseline("pid", "itae", "joint PID tuned on ITAE"),
    "computed_torque": Baseline(
        "computed_torque",
        None,
        "computed-torque PID (uses M(q), as the proposed law), tuned under the comparison's "
        "criterion",
    ),
}
#: ``eval.baselines``' default: every baseline.
DEFAULT_BASELINES = list(BASELINES)


def own_label(controller: str) -> str:
    """The label of a policy's own controller: ``adaptive`` or the controller's name."""
    return "adaptive" if controller == ADAPTIVE else controller


#: Every label a policy's own controller can have (one per controller that can train a policy).
OWN_LABELS = ("adaptive", "pid", "computed_torque")
#: The labels `armexp play` takes: the policy's own controller, the ablation, a baseline.
PLAY_LABELS = list(dict.fromkeys([*OWN_LABELS, ADAPTIVE_OFF, *BASELINES]))


def reference_label(criterion: str) -> str:
    """``adaptive_<criterion>``: the adaptive law tuned under ``criterion``."""
    return f"adaptive_{criterion}"


def baseline_criterion(name: str, comparison: str) -> str:
    """The criterion baseline ``name`` is tuned under, given the comparison's criterion."""
    return BASELINES[name].criterion or comparison


def reference_criteria(baselines: Iterable[str], own_criterion: str, comparison: str) -> list[str]:
    """The criteria of the ``adaptive_<criterion>`` rows an adaptive policy's comparison needs:
    those of its baselines that differ from the criterion of the policy's own gains (``config``
    for configured gains, which every tuned baseline then differs from), in baseline order."""
    out: list[str] = []
    for name in baselines:
        criterion = baseline_criterion(name, comparison)
        if criterion != own_criterion and criterion not in out:
            out.append(criterion)
    return out


def title(label: str) -> str:
    """How a label is named for a reader (animation titles)."""
    if label.startswith("adaptive_") and label != ADAPTIVE_OFF:
        criterion = label.removeprefix("adaptive_")
        return f"adaptive (tuned on {CRITERION_NAMES.get(criterion, criterion.upper())})"
    return TITLES.get(label, label)


#: How a criterion is named for a reader.
CRITERION_NAMES = {"gaing": "W", "itae": "ITAE", "iae": "IAE"}


TITLES = {
    "adaptive": "proposed (adaptive)",
    ADAPTIVE_OFF: "adaptive, adaptation off",
    "pid": "PID",
    "pid_gaing": "PID (tuned on W)",
    "pid_itae": "PID (tuned on ITAE)",
    "computed_torque": "computed torque",
}
