"""The controllers `armexp eval` and `armexp play` run a policy with: their labels, roles, gains and
where the gains came from (docs/design.md §4, §8; the labels are `armexp.baselines`').

* the policy's own controller (role ``proposed``, label ``adaptive`` for subsystem_adaptive): the
  gains it was trained with (``<section>.adaptive_gains=tuned``, criterion that of the train run's
  tune run, ``config`` when it trained with configured gains) or ``controller.gains`` as composed
  (``<section>.adaptive_gains=config``);
* ``adaptive_off`` (role ``ablation``): the same law and gains with adaptation off (b1 = 0);
* each baseline of ``eval.baselines`` (role ``baseline``): tuned under its criterion
  (``<section>.tune_runs.<name>`` or the latest matching tune run, `armexp.gains.resolve`) or
  configured (``<section>.baseline_gains=config``); ``compare_with`` names the proposed label it
  is compared with;
* ``adaptive_<criterion>`` (role ``reference``): the adaptive law tuned under a baseline's
  criterion where that differs from the policy's gains' criterion, the proposed side of that
  baseline's comparison.
"""

from __future__ import annotations

import copy
import dataclasses
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from armexp import run_names, tracking
from armexp.agents.callbacks import MODEL_DIR, MODEL_FILE
from armexp.agents.factory import load_agent
from armexp.baselines import (
    ABLATION,
    ADAPTIVE,
    ADAPTIVE_OFF,
    BASELINE,
    BASELINES,
    CONFIG,
    PROPOSED,
    REFERENCE,
    baseline_criterion,
    own_label,
    reference_criteria,
    reference_label,
)
from armexp.config import ConfigError
from armexp.gains import Gains, criterion_of, resolve, run_criterion, run_horizon, tuned
from armexp.gains import without_adaptation as adaptation_off
from armexp.stages.train import TUNE_RUN_TAG
from armexp.tags import ADAPTIVE_GAINS_TAG, TRAIN_RUN_TAG

log = logging.getLogger(__name__)

#: The eval run's artifact that describes every label (`Entry.record`).
CONTROLLERS_FILE = "controllers.yaml"


def tune_run_tag(label: str) -> str:
    """The tag with the tune run a label's gains came from: ``armexp.tune_run.<label>``."""
    return f"{TUNE_RUN_TAG}.{label}"


@dataclass(frozen=True)
class Entry:
    """One controller an eval runs: its label, role, gains and (a baseline) the proposed label it
    is compared with."""

    label: str
    role: str
    gains: Gains
    compare_with: str | None = None

    @property
    def controller(self) -> str:
        return self.gains.controller

    def record(self) -> dict[str, Any]:
        """Its entry in ``controllers.yaml``."""
        g = self.gains
        return {"controller": g.controller, "role": self.role, "criterion": g.criterion,
                "horizon": g.horizon, "tune_run": g.tune_run, "gains": g.values,
                "compare_with": self.compare_with}  # fmt: skip


@dataclass
class Policy:
    """A train run's policy, the config it was trained with (its environment; the episode
    targets are the caller's ``tasks``), its own controller, and the lineage tags of the run
    that uses it."""

    train_id: str
    train_cfg: DictConfig
    model: Any
    own: Entry
    tags: dict[str, str]

    @property
    def robot(self) -> str:
        return str(self.train_cfg.robot.name)


def _train_run(cfg: DictConfig, section: str) -> Any:
    return tracking.find_stage_run(
        cfg,
        "train",
        run_id=cfg[section].train_run,
        # The circles too: a run with overridden circles keeps its obstacle set's name.
        match={
            "robot.name": str(cfg.robot.name),
            "obstacles.name": str(cfg.obstacles.name),
            "obstacles.circles": tracking.flatten(cfg.obstacles)["circles"],
        },
        key=f"{section}.train_run",
    )


def load_policy(cfg: DictConfig, section: str) -> Policy:
    """The policy of ``<section>.train_run`` (or the latest matching train run) with its own
    controller's gains per ``<section>.adaptive_gains``."""
    train_run = _train_run(cfg, section)
    train_id = train_run.info.run_id
    train_cfg = OmegaConf.load(_policy_artifact(cfg, section, train_id, "config.yaml"))
    assert isinstance(train_cfg, DictConfig)
    # The episode targets are this run's choice; the environment is the policy's.
    train_cfg.tasks = cfg.tasks
    trained_with = str(train_cfg.controller.name)
    source = str(cfg[section].adaptive_gains)
    tags = {TRAIN_RUN_TAG: train_id, ADAPTIVE_GAINS_TAG: source}
    if source == CONFIG:
        if str(cfg.controller.name) != trained_with:
            raise ConfigError(
                f"{section}.adaptive_gains=config is not allowed with "
                f"controller={cfg.controller.name}: the policy was trained with {trained_with}; "
                f"compose controller={trained_with}."
            )
        values = OmegaConf.to_container(cfg.controller.gains, resolve=True)
        assert isinstance(values, dict)
        own = Gains(trained_with, {str(k): v for k, v in values.items()}, CONFIG, None, None)
    else:
        values = yaml.safe_load(_policy_artifact(cfg, section, train_id, "gains.yaml").read_text())
        own = _trained_gains(cfg, train_run, trained_with, values)
        if own.tune_run:
            tags[TUNE_RUN_TAG] = own.tune_run
    for tag in (run_names.AGENT_PRESET_TAG, run_names.AGENT_ALGO_TAG):  # named after the policy
        if train_run.data.tags.get(tag):
            tags[tag] = train_run.data.tags[tag]
    model_path = _policy_artifact(cfg, section, train_id, f"{MODEL_DIR}/{MODEL_FILE}")
    model = load_agent(str(model_path), None, train_cfg.agent)
    entry = Entry(own_label(trained_with), PROPOSED, own)
    return Policy(train_id, train_cfg, model, entry, tags)


#: What each artifact of a train run that a policy is loaded from is, for the sentence that
#: says it is missing.
POLICY_ARTIFACTS = {"config.yaml": "the config it trained with", "gains.yaml": "its gains",
                    f"{MODEL_DIR}/{MODEL_FILE}": "its final model"}  # fmt: skip


def _policy_artifact(cfg: DictConfig, section: str, train_id: str, path: str) -> Path:
    """The artifact ``path`` of the policy's train run, downloaded; a `ConfigError` naming the
    run and the artifact when the run has none (deleted, or never written)."""
    try:
        return tracking.download_artifact(train_id, path, cfg)
    except (MlflowException, OSError):
        folder, _, name = path.rpartition("/")
        client = MlflowClient(tracking.store_uri(cfg))
        if any(Path(f.path).name == name for f in client.list_artifacts(train_id, folder or None)):
            raise  # it is there: something else went wrong
    if cfg[section].train_run:
        run = f"{section}.train_run={train_id} is not allowed: that train run"
    else:
        run = f"{section}.train_run is not set, and the latest matching train run {train_id}"
    raise ConfigError(
        f"{run} has no artifact {path} ({POLICY_ARTIFACTS[path]}; it was deleted or never "
        "written); train again, or give another train run."
    )


#: The config sections a policy brings from its train run: the arm, its obstacles and its
#: environment (`armexp.envs.factory.settings_from_config` builds the episodes from them).
POLICY_SECTIONS = ("robot", "obstacles", "env")


def as_run(composed: DictConfig, policy: Policy, stage: str) -> DictConfig:
    """``composed`` with the policy's arm, obstacles and environment (its train run's), which
    are what the episodes ran on: the config the eval or play run records. A composed robot
    other than the policy's is said on one line."""
    differ = [key for key in POLICY_SECTIONS
              if _plain(composed.get(key)) != _plain(policy.train_cfg.get(key))]  # fmt: skip
    if not differ:
        return composed
    if str(composed.robot.name) != policy.robot:
        print(
            f"{stage}: the policy of train run {policy.train_id[:8]} was trained on "
            f"robot={policy.robot}, which runs here and is recorded (robot={composed.robot.name} "
            "was composed)"
        )
    out = copy.deepcopy(composed)
    for key in differ:
        try:  # merged into the composed node, which keeps its schema's types
            merged = OmegaConf.merge(out[key], policy.train_cfg[key])
        except OmegaConfBaseException as exc:  # a train run of an older config's keys
            log.warning("%s: the run records the composed %s (%s)", stage, key, exc)
            continue
        with open_dict(out):
            out[key] = merged
    return out


def _plain(node: Any) -> Any:
    return OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else node


def _trained_gains(cfg: DictConfig, train_run: Any, controller: str, values: Any) -> Gains:
    """The gains a train run trained with, and the criterion of the tune run they came from."""
    tune_id = train_run.data.tags.get(TUNE_RUN_TAG)
    if not tune_id:
        return Gains(controller, values, CONFIG, None, None)
    tune = tracking.find_stage_run(
        cfg, "tune", run_id=tune_id, key=f"the tune run of train run {train_run.info.run_id}"
    )
    return Gains(controller, values, run_criterion(tune), run_horizon(tune), tune_id)


def baseline_entry(
    cfg: DictConfig, section: str, policy: Policy, name: str, compare_with: str | None
) -> Entry:
    """Baseline ``name`` for ``policy``'s robot, its gains per ``<section>.baseline_gains``."""
    stage = cfg[section]
    found = resolve(
        cfg, BASELINES[name].controller, policy.robot, str(stage.baseline_gains),
        criterion=baseline_criterion(name, criterion_of(cfg)),
        run_id=stage.tune_runs.get(name), key=f"{section}.tune_runs.{name}",
    )  # fmt: skip
    return Entry(name, BASELINE, found, compare_with)


def ablation_entry(policy: Policy) -> Entry:
    """``adaptive_off``: the policy's adaptive law and gains with adaptation off."""
    own = policy.own.gains
    return Entry(
        ADAPTIVE_OFF, ABLATION, dataclasses.replace(own, values=adaptation_off(own.values))
    )


def controller_set(cfg: DictConfig, policy: Policy) -> list[Entry]:
    """Every label `armexp eval` runs, in order: the policy's own controller, the ablation, the
    baselines of ``eval.baselines``, then the ``adaptive_<criterion>`` references they need."""
    stage = cfg.eval
    own = policy.own
    adaptive = own.controller == ADAPTIVE
    names = [str(b) for b in stage.baselines]
    if own.label in names:  # a policy trained with a baseline's controller runs it already
        log.warning("eval: %s is the policy's own controller; not run again", own.label)
        names.remove(own.label)
    entries = [own]
    if stage.ablation and adaptive:
        entries.append(ablation_entry(policy))
    comparison = criterion_of(cfg)
    tuned_baselines = str(stage.baseline_gains) == "tuned"
    for name in names:
        criterion = baseline_criterion(name, comparison)
        same = not (adaptive and tuned_baselines) or criterion == own.gains.criterion
        compare = own.label if same else reference_label(criterion)
        entries.append(baseline_entry(cfg, "eval", policy, name, compare))
    if adaptive and tuned_baselines:
        for criterion in reference_criteria(names, own.gains.criterion, comparison):
            label = reference_label(criterion)
            found = tuned(
                cfg, ADAPTIVE, policy.robot, criterion, stage.tune_runs.get(label),
                key=f"eval.tune_runs.{label}",
            )  # fmt: skip
            entries.append(Entry(label, REFERENCE, found))
    return entries


def play_entry(cfg: DictConfig, policy: Policy) -> Entry:
    """The label ``play.controller`` names (null: the policy's own controller)."""
    own = policy.own
    label = str(cfg.play.controller) if cfg.play.controller else own.label
    if label == own.label:
        return own
    if label == ADAPTIVE_OFF and own.controller == ADAPTIVE:
        return ablation_entry(policy)
    if label in BASELINES:
        return baseline_entry(cfg, "play", policy, label, own.label)
    raise ConfigError(
        f"play.controller={label} is not allowed: the policy of train run {policy.train_id} was "
        f"trained with {own.controller} (label {own.label}); choose {own.label}, "
        + (f"{ADAPTIVE_OFF}, " if own.controller == ADAPTIVE else "")
        + f"or a baseline ({', '.join(BASELINES)})."
    )


def lineage_tags(entries: list[Entry]) -> dict[str, str]:
    """``armexp.tune_run.<label>`` for every label whose gains came from a tune run."""
    return {tune_run_tag(e.label): e.gains.tune_run for e in entries if e.gains.tune_run}
