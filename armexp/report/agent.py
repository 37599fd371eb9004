"""Which agent produced a result: its preset, its learning aids and the budget it spent.

The paper's agent is model-free SAC that learns from interaction alone (docs/design.md §7). A preset
that adds a learning aid using privileged knowledge of the planner or the obstacles (demonstrations,
cloning, an expert's labels) is *aided*, and every table built from it says so. Aids that use no
such knowledge (weight averaging, …) are named too, but do not make a run aided.

Everything is read from the train run: the preset from the tag ``armexp.agent_preset`` (Hydra's
``agent`` group choice) or else the param ``agent.name``; the algorithm from the tag
``armexp.agent_algo`` or else its config (SAC for runs from before ``agent.algo``); the aids
from the run's resolved ``config.yaml`` (else its ``agent.*`` params); the budget spent from its
``final/*`` metrics (else the last values logged while training).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import yaml
from mlflow.entities import Run

from armexp import aids
from armexp.config.agent_schema import TITLES, agent_label
from armexp.report.runs import metric_value
from armexp.tags import AGENT_ALGO_TAG, AGENT_LEFT_OUT_TAG, AGENT_PRESET_TAG, STOP_REASON_TAG

#: Train-run metrics of the budget spent, newest name first (final/* are logged at the end;
#: the others while training, so a KILLED run still shows how far it got).
SPENT_METRICS = {
    "env_steps": ("final/env_steps", "time/total_timesteps"),
    "episodes": ("final/episodes", "rollout/episodes"),
    "wall_s": ("final/wall_s", "time/wall_s"),
    "demo_steps": ("demonstrations/steps",),
}


@dataclass(frozen=True)
class Aid:
    """One learning aid that is on: a short name for captions, its setting for Table II."""

    name: str
    detail: str
    privileged: bool


@dataclass
class AgentInfo:
    """The agent of one train run, as used."""

    train_run: str
    preset: str
    aids: list[Aid] = field(default_factory=list)
    spent: dict[str, float] = field(default_factory=dict)
    stop_reason: str = ""
    status: str = ""
    known: bool = True
    #: Empty: evaluated with the gains it was trained with; else e.g. "paper gains".
    gains: str = ""
    #: Its ``agent.algo``, and the preset's options that algorithm does not read.
    algo: str = "sac"
    left_out: tuple[str, ...] = ()

    @property
    def algorithm(self) -> str:
        """The algorithm's name as tables give it (``TD3``)."""
        return TITLES.get(self.algo, self.algo)

    @property
    def aided(self) -> bool:
        return any(a.privileged for a in self.aids)

    @property
    def label(self) -> str:
        """``preset (aided: …)``: what a caption says about this agent."""
        if not self.known:
            return f"unknown (train run {self.train_run or '?'} is not in this store)"
        privileged = [a.name for a in self.aids if a.privileged]
        other = [a.name for a in self.aids if not a.privileged]
        gains = f", evaluated with {self.gains}" if self.gains else ""
        if privileged:
            text = f"aided: {', '.join(privileged)}"
            if other:
                text += f"; also {', '.join(other)}"
            return f"{self.preset} ({text}){gains}"
        if other:
            aids = ", ".join(other)
            return f"{self.preset} (learning aids without privileged knowledge: {aids}){gains}"
        return f"{self.preset} (plain {self.algorithm}, no learning aids){gains}"


def _num(value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return 0.0
    return out if math.isfinite(out) else 0.0


def _g(value: Any) -> str:
    return f"{_num(value):g}"


@dataclass(frozen=True)
class _Legacy:
    """An agent key that set an aid before aids were composed from ``agent.aids``: the add-on
    that does the same now (its name in `armexp.aids`) and the argument the key's
    value was; or, for an aid since removed, its name, its detail from the value and whether it
    used privileged knowledge."""

    key: str
    aid: str = ""
    arg: str = ""
    name: str = ""
    detail: Callable[[Any], str] = str
    privileged: bool = False


#: Runs stored before aids were composed from ``agent.aids`` set them with these agent keys.
LEGACY_AIDS = (
    _Legacy("demonstrations", "demonstrations", "episodes"),
    _Legacy("bc_weight", "cloning", "weight"),
    _Legacy("bc_expert", "expert"),
    _Legacy("shaping", name="planner reward shaping", privileged=True,
            detail=lambda v: f"reward shaped by the planner's time to go ({_g(v)} per s)"),
    _Legacy("relabel", name="hindsight relabelling",
            detail=lambda v: f"hindsight relabelling ({_num(v) * 100:g} % of each batch)"),
    _Legacy("clearance", name="collision clearance",
            detail=lambda v: f"collisions counted {_g(v)} m from the obstacles in training"),
    _Legacy("average_tail", "averaging", "tail"),
)  # fmt: skip


def _declared_aid(target: str, args: Mapping[str, Any]) -> Aid | None:
    """The aid of a declared add-on (`armexp.aids`), as its declaration names it."""
    found = aids.declared(target)
    if found is None:
        return None
    return Aid(found.title, found.describe(args), found.privileged)


def aids_of(agent: Mapping[str, Any], train: Mapping[str, Any] | None = None) -> list[Aid]:
    """The learning aids an agent config (and the train stage's config) turn on."""
    train = train or {}
    out: list[Aid] = []
    for old in LEGACY_AIDS:
        value = agent.get(old.key)
        if value is True or (value is not False and _num(value) > 0):
            known = _declared_aid(old.aid, {old.arg: value}) if old.aid else None
            out.append(known or Aid(old.name, old.detail(value), old.privileged))
    if train.get("keep_best") is True and _num(train.get("eval_every")) > 0:
        out.append(
            Aid(
                "best-check selection",
                "final model: the best of the held-out checks while training",
                False,
            )
        )
    specs = agent.get("aids")
    for key, spec in specs.items() if isinstance(specs, Mapping) else ():
        if not isinstance(spec, Mapping):
            continue
        # A spec names its add-on by _target_; one stored without it, by its preset name.
        target = spec.get("_target_")
        known = _declared_aid(target if isinstance(target, str) else str(key), spec)
        if known is not None:
            out.append(known)
    for target in _targets(agent):
        if aids.declared(target) is not None:
            continue  # described above
        module, _, name = target.rpartition(".")
        privileged = any(module.startswith(m) for m in aids.privileged_modules())
        out.append(Aid(name or target, f"add-on {target}", privileged))
    return out


def _targets(node: Any) -> list[str]:
    """``_target_`` of every add-on composed into the agent config (Hydra instantiation)."""
    found: list[str] = []
    if isinstance(node, Mapping):
        if isinstance(node.get("_target_"), str):
            found.append(node["_target_"])
        for key, value in node.items():
            if key != "_target_":
                found += _targets(value)
    elif isinstance(node, Sequence) and not isinstance(node, str):
        for value in node:
            found += _targets(value)
    return found


def _from_params(params: Mapping[str, str], prefix: str) -> dict[str, Any]:
    """The params under ``prefix`` as a config; ``aids.<name>.<arg>`` (the aids flattened into
    params) back under ``aids``, one config per aid."""
    out: dict[str, Any] = {}
    for key, text in params.items():
        if key.startswith(prefix):
            try:
                value = yaml.safe_load(text)
            except yaml.YAMLError:
                value = text
            name = key[len(prefix) :]
            where, _, arg = name.partition(".")
            if where == "aids" and arg.count(".") == 1:
                aid, _, arg = arg.partition(".")
                out.setdefault("aids", {}).setdefault(aid, {})[arg] = value
            else:
                out[name] = value
    return out


def agent_info(train_id: str, run: Run | None, cfg: Mapping[str, Any] | None) -> AgentInfo:
    """The agent of train run ``train_id`` (``run`` None: not in the store)."""
    if run is None:
        return AgentInfo(train_run=train_id, preset="unknown", known=False)
    params, tags, metrics = run.data.params, run.data.tags, run.data.metrics
    agent = dict(cfg["agent"]) if cfg and isinstance(cfg.get("agent"), Mapping) else {}
    agent = agent or _from_params(params, "agent.")
    train = dict(cfg["train"]) if cfg and isinstance(cfg.get("train"), Mapping) else {}
    train = train or _from_params(params, "train.")
    preset = tags.get(AGENT_PRESET_TAG) or params.get("agent.name") or str(agent.get("name") or "?")
    algo = tags.get(AGENT_ALGO_TAG) or str(agent.get("algo") or "sac")
    left_out = tags.get(AGENT_LEFT_OUT_TAG, "none")
    spent = {}
    for key, names in SPENT_METRICS.items():
        for name in names:
            if name in metrics:
                spent[key] = metric_value(metrics[name])
                break
    return AgentInfo(
        train_run=train_id,
        preset=agent_label(preset, algo) or preset,
        aids=aids_of(agent, train),
        spent=spent,
        stop_reason=tags.get(STOP_REASON_TAG, ""),
        status=run.info.status,
        algo=algo,
        left_out=tuple(k for k in left_out.split(",") if k and left_out != "none"),
    )


def caption(infos: Sequence[AgentInfo], counts: Sequence[int] | None = None) -> str:
    """One line naming the agent(s) behind a table, and whether they were aided.

    ``counts``: how many eval runs each agent produced (said when there are several agents).
    """
    labels: dict[str, int] = {}
    for i, info in enumerate(infos):
        labels[info.label] = labels.get(info.label, 0) + (counts[i] if counts else 1)
    if not labels:
        return "Agent: unknown (no train run recorded)."
    not_plain = any(i.aids or i.algo != "sac" for i in infos if i.known)
    trailer = " — not the paper's plain SAC" if not_plain else ""
    if len(labels) == 1:
        return f"Agent: {next(iter(labels))}{trailer}."
    parts = [f"{label} in {n} eval run{'s' if n != 1 else ''}" for label, n in labels.items()]
    return f"Agents: {'; '.join(parts)}."
