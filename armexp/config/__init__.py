"""Config tree location, schema registration, composition and validation.

`validate` is the single gate every stage passes: it turns any mistake (unknown option, wrong type,
bad value, inconsistent lengths) into a `ConfigError` whose message is one sentence naming the key,
the value and what is allowed.
"""

from __future__ import annotations

import dataclasses
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from importlib import resources
from pathlib import Path
from typing import Any

from hydra import compose, initialize_config_dir
from hydra.core.config_store import ConfigStore
from hydra.core.global_hydra import GlobalHydra
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.errors import HydraException
from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from armexp.config.agent_schema import ALGORITHMS
from armexp.config.checks import Check, ConfigError, fail
from armexp.config.errors import translate_error
from armexp.config.filters import check_filter
from armexp.config.paths import check_paths, expand_home
from armexp.config.run_keys import quote_ids, takes_ids
from armexp.config.schema import SCHEMAS, ArmexpConfig
from armexp.config.workspace import target_problem, workspace_checks

__all__ = ["ALGORITHMS", "ConfigError", "check_aid", "compose_config", "compose_unchecked",
           "config_dir", "expand_home", "register_schemas", "target_problem",
           "validate"]  # fmt: skip


def config_dir() -> Path:
    """The `conf/` tree: the checkout's when running from source, else the installed copy."""
    source = Path(__file__).resolve().parents[2] / "conf"
    if (source / "config.yaml").is_file():
        return source
    return Path(str(resources.files("armexp.conf")))


def register_schemas() -> None:
    cs = ConfigStore.instance()
    cs.store(name="armexp_schema", node=ArmexpConfig)
    for path, node in SCHEMAS.items():
        group, name = path.split("/")
        cs.store(group=group, name=name, node=node)


@contextmanager
def _hydra_context() -> Iterator[None]:
    register_schemas()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
            yield
    finally:
        GlobalHydra.instance().clear()


def compose_config(overrides: Sequence[str] = (), stage: str | None = None) -> DictConfig:
    """Compose the root config with Hydra's compose API, translating errors to `ConfigError`,
    and `validate` it for ``stage``."""
    cfg = compose_unchecked(overrides)
    validate(cfg, stage)
    return cfg


def compose_unchecked(overrides: Sequence[str] = (), hydra: bool = False) -> DictConfig:
    """The root config as Hydra composes it (with its ``hydra`` node: ``hydra``), errors as
    `ConfigError`, values not yet validated."""
    overrides = normalize_overrides(overrides)
    try:
        for override in OverridesParser.create().parse_overrides(overrides):
            if override.is_sweep_override():
                raise ConfigError(
                    f"{override.input_line} is a sweep, which runs one job per value: add -m "
                    "(--multirun) to sweep, or write a list in brackets."
                )
        with _hydra_context():
            return compose(
                config_name="config", overrides=list(overrides), return_hydra_config=hydra
            )
    except ConfigError:
        raise
    except (HydraException, OmegaConfBaseException, ValueError) as exc:
        raise translate_error(exc, overrides) from None


#: Config maps keyed by the user: ``eval.tune_runs.pid_itae=<id>`` (or ``={pid_itae: <id>}``)
#: adds or replaces a key.
USER_KEYED = ("eval.tune_runs", "play.tune_runs")


def normalize_overrides(overrides: Sequence[str]) -> list[str]:
    """Accept ``a.b=option`` for the nested group ``a/b`` (``controller.gains=paper``),
    ``eval.tune_runs.<label>=<id>`` without Hydra's ``++`` (`USER_KEYED`), run ids that Hydra
    would read as numbers (`armexp.config.run_keys.quote_ids`), and ``~`` for the home folder in
    a folder's key (`armexp.config.paths.expand_home`)."""
    out = []
    for o in map(expand_home, overrides):
        key, eq, value = o.partition("=")
        if eq and takes_ids(key):
            value = quote_ids(value)
            o = f"{key}={value}"
        if eq and (key in USER_KEYED or key.startswith(tuple(f"{k}." for k in USER_KEYED))):
            out.append(f"++{o}")
            continue
        group = key.replace(".", "/")
        nested_group = eq and "." in key and not key.startswith(("+", "~", "hydra"))
        options = group_options(group) if nested_group else []
        if options and value in options:
            o = f"{group}={value}"
        elif options and re.fullmatch(r"[A-Za-z_][\w-]*", value):
            # A bare name for a key that is a config group: a misspelt option.
            raise ConfigError(
                f"{key}={value} is not allowed: choose one of: {', '.join(sorted(options))}."
            )
        out.append(o)
    return out


def group_options(group: str) -> list[str]:
    folder = config_dir() / group
    return sorted(p.stem for p in folder.glob("*.yaml"))


# ---------------------------------------------------------------------------------- validation
def validate(cfg: DictConfig, stage: str | None = None) -> None:
    """Check field values against their schema checks, then the cross-field rules; ``stage``:
    the stage that will run on ``cfg`` (a section only another stage reads is not held to its
    rules), None for every rule."""
    _walk(cfg, "")
    check_paths(cfg)
    _cross_checks(cfg)
    workspace_checks(cfg, stage)
    _agent_checks(cfg)
    check_filter(cfg)


def _walk(node: Any, path: str) -> None:
    if isinstance(node, DictConfig):
        kind = OmegaConf.get_type(node)
        checks: dict[str, Check] = {}
        if kind is not None and dataclasses.is_dataclass(kind):
            for f in dataclasses.fields(kind):
                if "check" in f.metadata:
                    checks[f.name] = f.metadata["check"]
        known: set[str] = set()
        if kind is not None and dataclasses.is_dataclass(kind):
            known = {f.name for f in dataclasses.fields(kind)}
        for key in node:
            sub = f"{path}.{key!s}" if path else str(key)
            if known and key not in known:
                # A key added with `+` that no code reads would be silently ignored.
                raise ConfigError(
                    f"{sub} is not a config key: {path or 'the root'} has "
                    + ", ".join(sorted(known))
                    + "."
                )
            if OmegaConf.is_missing(node, key):
                continue
            child = node[key]
            if key in checks:
                plain = OmegaConf.to_container(child) if _is_container(child) else child
                if not checks[key](plain):
                    raise fail(sub, plain, checks[key].allowed)
            _walk(child, sub)
    elif isinstance(node, ListConfig):
        for i, child in enumerate(node):
            _walk(child, f"{path}[{i}]")


def _is_container(x: Any) -> bool:
    return isinstance(x, DictConfig | ListConfig)


def _cross_checks(cfg: DictConfig) -> None:
    robot = cfg.get("robot")
    if robot is None or OmegaConf.is_missing(cfg, "robot"):
        return
    n = len(robot.lengths)
    if n == 0:
        raise fail("robot.lengths", [], "give one length per link")
    per_joint = ["masses", "q0", "joint_lower", "joint_upper", "velocity_bound"]
    for key in per_joint:
        _need_len(f"robot.{key}", robot[key], n)
    for j in range(n):
        lo, hi = robot.joint_lower[j], robot.joint_upper[j]
        if not lo < hi:
            raise fail(
                f"robot.joint_lower[{j}]", lo, f"it must be below robot.joint_upper[{j}]={hi}"
            )
        if not lo <= robot.q0[j] <= hi:
            raise fail(f"robot.q0[{j}]", robot.q0[j], f"it must lie within [{lo}, {hi}]")
    unc = robot.uncertainty
    for key in ("tau_d_cos_amp", "tau_d_cos_freq", "tau_d_rand_amp"):
        if unc[key] is not None:
            _need_len(f"robot.uncertainty.{key}", unc[key], n)
    for i, term in enumerate(unc.f_terms):
        for key in ("joint", "of"):
            if not 1 <= term[key] <= n:
                raise fail(f"robot.uncertainty.f_terms[{i}].{key}", term[key], f"joints are 1..{n}")
    if robot.torque_limit is not None:
        _need_len("robot.torque_limit", robot.torque_limit, n)
        for j, v in enumerate(robot.torque_limit):
            if not v > 0:
                raise fail(f"robot.torque_limit[{j}]", v, "it must be > 0 (null for none)")
    evaluation = cfg.get("eval")
    if evaluation is not None:
        span = min(hi - lo for lo, hi in zip(robot.joint_lower, robot.joint_upper, strict=True))
        for key in ("initial_offset", "large_offset"):
            if evaluation[key] is not None and evaluation[key] > span:
                raise fail(
                    f"eval.{key}", evaluation[key],
                    f"it must not exceed the smallest joint range ({span:.4g} rad)",
                )  # fmt: skip
    ctrl = cfg.get("controller")
    if ctrl is None or OmegaConf.is_missing(cfg, "controller"):
        return
    if ctrl.name in ("pid", "computed_torque"):
        for key in ("kp", "ki", "kd"):
            _need_len(f"controller.gains.{key}", ctrl.gains[key], n)
    tuner = cfg.get("tuner")
    log_space = tuner is not None and not OmegaConf.is_missing(cfg, "tuner") and tuner.log_space
    for name, box in ctrl.bounds.items():
        if len(box) != 2:
            raise fail(f"controller.bounds.{name}", list(box), "give [lower, upper]")
        if log_space and not box[0] > 0:
            raise ConfigError(
                f"controller.bounds.{name}={list(box)} is not allowed: the search is in log "
                "space (tuner.log_space=true), so both bounds must be > 0."
            )
        if not box[0] < box[1]:
            raise ConfigError(
                f"controller.bounds.{name}={list(box)} is not allowed: the lower bound "
                f"{box[0]} must be below the upper bound {box[1]}."
            )
    scenario = cfg.get("scenario")
    has_scenario = scenario is not None and not OmegaConf.is_missing(cfg, "scenario")
    if has_scenario and len(scenario.offset) not in (1, n):
        raise fail("scenario.offset", list(scenario.offset), f"give 1 or {n} values")
    dt = float(ctrl.dt)
    env = cfg.get("env")
    if env is not None and not OmegaConf.is_missing(cfg, "env"):
        _need_whole_periods("env.action_period", float(env.action_period), dt)
    if tuner is not None and not OmegaConf.is_missing(cfg, "tuner"):
        _need_whole_periods(
            "tuner.objective.switch_period", float(tuner.objective.switch_period), dt
        )
        obj = tuner.objective
        if not obj.rise_low < obj.rise_high:
            raise fail(
                "tuner.objective.rise_low",
                obj.rise_low,
                f"it must be below tuner.objective.rise_high={obj.rise_high}",
            )


def _agent_checks(cfg: DictConfig) -> None:
    agent = cfg.get("agent")
    if agent is None or OmegaConf.is_missing(cfg, "agent"):
        return
    if agent.get("max_env_steps") is None and agent.get("max_minutes") is None:
        # Episodes alone end a run whose length nobody can foresee (sac_paper's 20000 episodes
        # run to 20 M steps); a budget in steps makes a seed's result the same on any machine.
        raise ConfigError(
            "agent.max_env_steps=null with agent.max_minutes=null is not allowed: a run needs a "
            "budget, agent.max_env_steps ≥ 1 (agent.max_minutes, when set, guards the wall time "
            "beside it)."
        )
    algo = str(agent.get("algo", "sac"))
    if algo != "sac" and agent.get("gradients") == "compiled":
        raise ConfigError(
            f"agent.gradients=compiled is not allowed with agent.algo={algo}: the compiled update "
            f"is SAC's own; use agent.gradients=autograd ({algo} runs its library's update) or "
            "agent.algo=sac."
        )
    dropout = agent.get("critic_dropout")
    if dropout is not None and algo == "sac" and agent.get("gradients") == "compiled":
        raise ConfigError(
            f"agent.critic_dropout={dropout} is not allowed with agent.gradients=compiled: the "
            "compiled update does not cover dropout critics; use agent.gradients=autograd."
        )
    if algo == "ppo":
        _rollout_fits(agent)
    # A privileged aid in a non-privileged preset is refused as such, whichever algorithm it
    # would also not apply to (`_non_privileged` passes over targets that are not class names).
    if agent.get("privileged") is False:
        _non_privileged(cfg)
    for name, spec in (agent.get("aids") or {}).items():
        target = spec.get("_target_") if isinstance(spec, DictConfig) else None
        if not isinstance(target, str) or "." not in target:
            raise fail(
                f"agent.aids.{name}", OmegaConf.to_container(spec) if isinstance(
                    spec, DictConfig) else spec,
                "each aid is a config with a _target_ naming its class (armexp.agents.addons)",
            )  # fmt: skip
        _check_aid_target(f"agent.aids.{name}", target, agent)


def _non_privileged(cfg: DictConfig) -> None:
    """A preset marked ``agent.privileged=false`` learns from what the agent observes and the
    environment's own reward only: an aid, or a training callback, declared privileged
    (`armexp.aids`) or living in a privileged aid's module is refused before a run starts."""
    from armexp import aids

    specs = {f"agent.aids.{k}": v for k, v in (cfg.agent.get("aids") or {}).items()}
    train = cfg.get("train")
    if train is not None and not OmegaConf.is_missing(cfg, "train"):
        specs |= {f"train.callbacks.{k}": v for k, v in (train.get("callbacks") or {}).items()}
    modules = aids.privileged_modules()
    for key, spec in specs.items():
        target = spec.get("_target_") if isinstance(spec, DictConfig) else None
        if not isinstance(target, str):
            continue
        declaration = aids.declared(target)
        privileged = (
            declaration.privileged
            if declaration is not None
            else target.rpartition(".")[0].startswith(modules)
        )
        if privileged:
            allowed = ", ".join(a.name for a in aids.AIDS if not a.privileged)
            raise ConfigError(
                f"{key} is not allowed with agent.privileged=false: {target.rpartition('.')[2]} "
                "uses privileged knowledge (the planner or the obstacles); a non-privileged "
                f"preset takes only aids without it ({allowed}), so remove it (~{key}) or use "
                "an aided preset."
            )


def _rollout_fits(agent: DictConfig) -> None:
    """PPO updates only on a full rollout: one that does not fit the step budget never trains."""
    rollout = int(agent.ppo.n_steps) * int(agent.n_envs)
    cap = agent.get("max_env_steps")
    if cap is not None and rollout > int(cap):
        raise ConfigError(
            f"agent.ppo.n_steps={agent.ppo.n_steps} is not allowed with agent.n_envs="
            f"{agent.n_envs} and agent.max_env_steps={cap}: one PPO rollout ({rollout} steps) "
            f"must fit the budget, so give agent.ppo.n_steps ≤ {int(cap) // int(agent.n_envs)}."
        )


def _check_aid_target(key: str, target: str, agent: DictConfig) -> None:
    """`check_aid` for the add-on class ``target`` names under the ``agent`` config: a declared
    aid's algorithms and conflicts from its declaration (`armexp.aids`, no agent code imported),
    another add-on's algorithms from its class; one
    that cannot be imported is left to building it, which says why
    (`armexp.agents.addons.build_addons`)."""
    from hydra.utils import get_class

    from armexp import aids

    name = target.rpartition(".")[2]
    algo = str(agent.get("algo", "sac"))
    declaration = aids.declared(target)
    if declaration is not None:
        check_aid(key, name, declaration.algorithms, algo)
        why = declaration.conflicts(agent)
        if why is not None:
            raise ConfigError(f"{key} is not allowed with {why}.")
        return
    try:
        kind = get_class(target)
    except Exception:
        return
    check_aid(key, name, getattr(kind, "algorithms", None), algo)


def check_aid(key: str, name: str, allowed: frozenset[str] | None, algo: str) -> None:
    """The add-on ``name`` at ``key``, which applies to the algorithms ``allowed`` (None: all),
    applies to ``agent.algo=algo``."""
    if allowed is not None and algo not in allowed:
        fits = [a for a in ALGORITHMS if a in allowed]
        raise ConfigError(
            f"{key} is not allowed with agent.algo={algo}: {name} applies to "
            f"agent.algo={', '.join(fits)} only; remove it (~{key}) or use "
            + (f"agent.algo={fits[0]}." if len(fits) == 1 else "one of those.")
        )


def _need_whole_periods(key: str, value: float, dt: float) -> None:
    periods = value / dt
    if abs(periods - round(periods)) > 1e-9 or round(periods) < 1:
        raise fail(
            key, value, f"it must be a whole number of controller periods (controller.dt={dt})"
        )


def _need_len(key: str, value: Any, n: int) -> None:
    if len(value) != n:
        raise fail(key, list(value), f"the robot has {n} joints, so give {n} values")
