"""Tables I and II of the paper computed from stored runs, written as Markdown, LaTeX (booktabs)
and CSV through `armexp.report.formatting.Table`.

* Table I: environment parameters (from the train run's config),
* Table II: agent parameters as used, beside the paper's (`armexp.paper`): the preset, its
  algorithm and learning aids (and whether any uses privileged knowledge), the algorithm's
  settings, the budget configured and the budget spent.

Table III is `armexp.report.performance`, the controller comparison and the ablation
`armexp.report.comparison`, the claim check `armexp.report.claims`, the CSO gains and the tuning
spread `armexp.report.tuning`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import pandas as pd

from armexp import paper
from armexp.config.agent_schema import TITLES
from armexp.report.agent import AgentInfo, aids_of, caption
from armexp.report.formatting import Table, plain


def _rad(x: float) -> str:
    frac = x / math.pi
    for den in (1, 2, 3, 4, 6, 12):
        num = frac * den
        if abs(num - round(num)) < 1e-9 and round(num) != 0:
            n = round(num)
            sign = "−" if n < 0 else ""
            top = f"{abs(n)}π" if abs(n) != 1 else "π"
            return f"{sign}{top}/{den}" if den != 1 else f"{sign}{top}"
    return f"{x:.4g}"


def table_one(train_cfg: dict[str, Any]) -> Table:
    env, robot = train_cfg["env"], train_cfg["robot"]
    limits = ", ".join(
        f"q{j + 1}: [{_rad(lo)}, {_rad(hi)}]"
        for j, (lo, hi) in enumerate(zip(robot["joint_lower"], robot["joint_upper"], strict=True))
    )
    rows = [
        ("Reach reward", env["reach_reward"]),
        ("Boundary penalty", env["boundary_penalty"]),
        ("Collision penalty", env["collision_penalty"]),
        ("Joint limits (rad)", limits),
        ("Reach threshold (m)", env["reach_threshold"]),
        ("Growth penalty", env["growth_penalty"]),
        ("Obstacles", train_cfg["obstacles"]["name"]),
    ]
    return _params_table("table1_environment", "Table I: DRL environment parameters", rows)


def table_two(train_cfg: dict[str, Any], agents: Sequence[AgentInfo] = ()) -> Table:
    """Agent parameters as used, beside the paper's: the preset, its algorithm and learning aids
    (whether any uses privileged knowledge), the algorithm's settings (the shared ones it does not
    read shown as "–"; its own after them), and the budget configured and spent.

    ``agents``: the selection's train runs (the first is the one whose config is ``train_cfg``);
    none: the aids are read from ``train_cfg`` and the budget spent is not known.
    """
    agent = train_cfg["agent"]
    algo = str(agent.get("algo") or "sac")
    infos = list(agents) or [
        AgentInfo(
            "", str(agent.get("name", "?")), aids_of(agent, train_cfg.get("train") or {}),
            algo=algo,
        )
    ]  # fmt: skip
    rows = [
        *_aid_rows(infos),
        ("Changed from Table II", changes(train_cfg, infos[0]), "–"),
        *_setting_rows(train_cfg, set(infos[0].left_out)),
        *_own_rows(agent, algo),
        *_spent_rows(infos),
    ]
    shown = pd.DataFrame(
        [(k, plain(v), plain(p)) for k, v, p in rows], columns=["Parameter", "Value", "Paper"]
    )
    return Table(
        "table2_agent",
        "Table II: DRL agent parameters as used",
        shown,
        shown.copy(),
        [_table_two_note(infos)],
        caption=caption(infos),
    )


#: A row of Table II: parameter, value as used, the paper's value.
Row = tuple[str, Any, Any]


def _aid_rows(infos: Sequence[AgentInfo]) -> list[Row]:
    """The preset(s), their learning aids (one text, or one per preset where they differ) and
    whether any aid uses privileged knowledge."""

    def aid_text(info: AgentInfo) -> str:
        return "; ".join(a.detail for a in info.aids) or "none"

    texts = {aid_text(i): i.preset for i in infos if i.known}
    aids = (
        next(iter(texts), "unknown")
        if len(texts) <= 1
        else " | ".join(f"{preset}: {text}" for text, preset in texts.items())
    )
    privileged = list(dict.fromkeys(a.name for i in infos for a in i.aids if a.privileged))
    aided = (
        f"yes: {', '.join(privileged)} (privileged knowledge of the planner or the obstacles) "
        "— not the paper's plain SAC"
        if privileged
        else "no"
    )
    return [
        ("Preset", ", ".join(dict.fromkeys(i.preset for i in infos)), "plain SAC"),
        ("Algorithm", ", ".join(dict.fromkeys(i.algorithm for i in infos)), "SAC"),
        ("Learning aids", aids, "none"),
        ("Aided", aided, "no"),
    ]


#: Table II's values as config keys, with the names the changes list gives them.
_PRINTED = {"batch_size": "batch size", "tau": "tau", "buffer_size": "buffer",
            "learning_starts": "initial random steps", "gamma": "gamma",
            "learning_rate": "learning rate", "episodes": "episodes"}  # fmt: skip
#: What Table II leaves open (`armexp.paper.TABLE_II_OPEN`), by the same names.
_OPEN = {"n_envs": "parallel environments", "n_steps": "n-step returns",
         "net_arch": "hidden layers", "critic_arch": "critic layers",
         "gradients": "gradients", "ent_coef": "entropy coefficient",
         "target_entropy": "entropy target",
         "critic_dropout": "critic dropout (DroQ)"}  # fmt: skip


def changes(train_cfg: dict[str, Any], info: AgentInfo) -> str:
    """Every way the run's agent differs from the paper's SAC (`armexp.paper.TABLE_II`, and
    ``agent=sac_paper`` where Table II gives no value), each as ``name paper → used``, led by
    whether any uses privileged knowledge (aided) or none does (not aided)."""
    agent, env = train_cfg["agent"], train_cfg.get("env") or {}
    printed, open_ = paper.TABLE_II, paper.TABLE_II_OPEN
    left_out = set(info.left_out)
    out: list[str] = []
    if str(agent.get("algo") or "sac") != "sac":
        out.append(f"algorithm SAC → {info.algorithm}")
    for key, name in _PRINTED.items():
        if key not in left_out and key in agent and agent[key] != printed[key]:
            out.append(f"{name} {plain(printed[key])} → {plain(agent[key])}")
    for key in ("action_period", "max_steps"):
        if key in env and env[key] != printed[key]:
            out.append(f"env.{key} {plain(printed[key])} → {plain(env[key])}")
    for key, name in _OPEN.items():
        if key not in left_out and agent.get(key, open_[key]) != open_[key]:
            out.append(f"{name} {_shown(open_[key])} → {_shown(agent.get(key))}")
    used = (agent.get("train_freq", 1), agent.get("gradient_steps", 1))
    if "gradient_steps" not in left_out and used != (open_["train_freq"], open_["gradient_steps"]):
        ratio = used[1] / (used[0] * int(agent.get("n_envs", 1)))
        out.append(
            f"gradient steps per environment step 1 → {ratio:g} ({used[1]} every {used[0]} "
            "step(s) of all environments)"
        )
    steps = agent.get("max_env_steps")
    if steps is not None and int(steps) < printed["episodes"] * printed["max_steps"]:
        out.append(f"budget ≤ {int(steps):,} environment steps")
    out += [a.detail for a in info.aids]
    privileged = [a.name for a in info.aids if a.privileged]
    lead = (
        f"aided ({', '.join(privileged)} use privileged knowledge)"
        if privileged
        else "not aided (none uses privileged knowledge)"
    )
    return f"{lead}: {'; '.join(out)}" if out else "none: the paper's SAC as printed"


def _shown(value: Any) -> str:
    if isinstance(value, list | tuple):
        return "×".join(str(int(v)) for v in value)
    return "–" if value is None else plain(value)


def _setting_rows(train_cfg: dict[str, Any], left_out: set[str]) -> list[Row]:
    """The agent's shared and the environment's settings in the train run's config, the budget
    configured; the shared settings its algorithm does not read (``left_out``) as "–"."""
    agent, env, robot = train_cfg["agent"], train_cfg["env"], train_cfg["robot"]
    printed = paper.TABLE_II
    title = TITLES.get(str(agent.get("algo") or "sac"), "?")

    def used(key: str, value: Any) -> Any:
        return f"– (not {title}'s)" if key in left_out else value

    def bounds(values: Sequence[float]) -> str:
        return ", ".join(f"q̇{j + 1}: [−{b:g}, +{b:g}]" for j, b in enumerate(values))

    lr = plain(agent["learning_rate"])
    if agent.get("lr_final") is not None:
        lr += f" → {plain(agent['lr_final'])} (linear over the budget)"
    budget = f"{plain(agent['episodes'])} episodes of ≤ {plain(env['max_steps'])} steps"
    if agent.get("max_env_steps") is not None:
        budget += f", ≤ {int(agent['max_env_steps']):,} env steps"
    if agent.get("max_minutes") is not None:
        budget += f", ≤ {float(agent['max_minutes']):g} min wall time"
    updates = f"{plain(agent['gradient_steps'])} every {plain(agent['train_freq'])} step(s)"
    nets = "×".join(str(int(u)) for u in agent.get("net_arch", []))
    if agent.get("critic_arch"):
        nets = f"actor {nets}, critics " + "×".join(str(int(u)) for u in agent["critic_arch"])
    return [
        (
            "Velocity bounds (rad/s)",
            bounds(robot["velocity_bound"]),
            bounds(printed["velocity_bound"]),
        ),
        ("Batch size", used("batch_size", agent["batch_size"]), printed["batch_size"]),
        ("Target smoothing factor", used("tau", agent["tau"]), printed["tau"]),
        (
            "Experience buffer length",
            used("buffer_size", agent["buffer_size"]),
            printed["buffer_size"],
        ),
        (
            "Initial random steps",
            used("learning_starts", agent["learning_starts"]),
            printed["learning_starts"],
        ),
        ("Discount factor", agent["gamma"], printed["gamma"]),
        ("Time step (s)", env["action_period"], printed["action_period"]),
        ("Max time steps/episode", env["max_steps"], printed["max_steps"]),
        ("Learning rate", lr, printed["learning_rate"]),
        ("n-step returns", used("n_steps", agent.get("n_steps", 1)), "–"),
        ("Hidden layers", nets or "–", "–"),
        ("Parallel environments", agent.get("n_envs", 1), "–"),
        (
            "Gradient steps per update",
            used("gradient_steps", updates),
            "–",
        ),
        ("Gradients", agent.get("gradients", "autograd"), "–"),
        (
            "Training budget",
            budget,
            f"{printed['episodes']} episodes of ≤ {printed['max_steps']} steps",
        ),
    ]


def _own_rows(agent: dict[str, Any], algo: str) -> list[Row]:
    """The options only ``algo`` has (its ``agent.<algo>`` section), and the entropy
    coefficient where the algorithm has one."""
    title = TITLES.get(algo, algo)
    rows: list[Row] = []
    if algo in ("sac", "tqc", "crossq"):
        rows.append(("Entropy coefficient", agent.get("ent_coef", "auto"), "–"))
    own = agent.get(algo)
    if isinstance(own, dict):
        rows += [(f"{title}: {key}", value, "–") for key, value in own.items()]
    return rows


def _spent(
    infos: Sequence[AgentInfo], key: str, show: Callable[[float], str], scale: float = 1.0
) -> str:
    """One budget-spent figure: the run's value, or the mean and range over several."""
    values = [i.spent[key] * scale for i in infos if math.isfinite(i.spent.get(key, math.nan))]
    if not values:
        return "not logged"
    if len(values) == 1:
        return str(show(values[0]))
    mean = sum(values) / len(values)
    return f"{show(mean)} (mean of {len(values)} runs, {show(min(values))}–{show(max(values))})"


def _spent_rows(infos: Sequence[AgentInfo]) -> list[Row]:
    """The budget spent by the train runs and what stopped them."""
    steps = _spent(infos, "env_steps", lambda v: f"{v:,.0f}")
    if any(i.spent.get("demo_steps", 0) > 0 for i in infos):
        demo = _spent(infos, "demo_steps", lambda v: f"{v:,.0f}")
        steps += f" (+ {demo} in planner demonstrations)"
    stopped = ", ".join(dict.fromkeys(i.stop_reason for i in infos if i.stop_reason))
    unfinished = sorted({i.status for i in infos if i.known and i.status != "FINISHED"})
    if unfinished:
        stopped = (stopped + "; " if stopped else "") + (
            f"{'/'.join(unfinished)} run: last values logged while training"
        )
    return [
        ("Env steps used", steps, "–"),
        ("Episodes used", _spent(infos, "episodes", lambda v: f"{v:,.0f}"), "–"),
        ("Wall time used (min)", _spent(infos, "wall_s", lambda v: f"{v:.1f}", 1 / 60), "–"),
        ("Stopped on", stopped or "not logged", "–"),
    ]


def _table_two_note(infos: Sequence[AgentInfo]) -> str:
    source = infos[0].train_run
    return (
        "Value: the train run's resolved config"
        + (f" (train run {source})" if source else "")
        + "; used: its final metrics"
        + (f", over the {len(infos)} train runs of the selection" if len(infos) > 1 else "")
        + ". Paper: its Table II (– where it gives no value). Aided: a learning aid uses "
        "privileged knowledge of the planner or the obstacles, which the paper's model-free "
        "SAC does not have."
    )


def _params_table(name: str, title: str, rows: list[tuple[str, Any]]) -> Table:
    shown = pd.DataFrame([(k, plain(v)) for k, v in rows], columns=["Parameter", "Value"])
    return Table(name, title, shown, shown.copy())
