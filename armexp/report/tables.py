"""The paper's tables computed from stored runs, written as Markdown, LaTeX (booktabs) and CSV.

* Table I: environment parameters (from the train run's config),
* Table II: agent parameters as used, beside the paper's: the preset, its learning aids (and
  whether any uses privileged knowledge), the budget configured and the budget spent;

and the `Table` every report table is written through. Table III is
`armexp.report.performance`, the controller comparison and the ablation
`armexp.report.comparison`, the claim check `armexp.report.claims`, the CSO gains and the tuning
spread `armexp.report.tuning`.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from armexp.config.agent_schema import TITLES
from armexp.report.agent import AgentInfo, aids_of, caption


def fmt(value: float, digits: int = 3) -> str:
    if not math.isfinite(value):
        return "–"
    return f"{value:.{digits}g}" if abs(value) < 1e-2 and value != 0 else f"{value:.{digits}f}"


@dataclass
class Context:
    """What the tables say beside their numbers: the agent behind them and how the eval runs
    measured (all read from the selected runs' params and tags)."""

    #: One line naming the agent(s) and whether they were aided (`armexp.report.agent.caption`).
    agent: str = ""
    #: ``eval.initial_offset`` as logged (e.g. "0.005 rad"); None: not logged.
    initial_offset: str | None = None
    #: ``eval.large_offset`` as logged (e.g. "0.05 rad"); None: not logged (or null).
    large_offset: str | None = None
    #: ``robot.torque_limit`` as logged (e.g. "±400, ±300 N·m"); None: not logged.
    torque_limit: str | None = None
    reach_threshold: float = 0.04
    #: ``env.action_period`` (s): the reach check runs once per action.
    action_period: float = 0.03
    #: An aided agent is shown and the paper's plain SAC is not among the selected runs.
    plain_missing: bool = False
    #: A sentence naming the seeds (``report.seeds``) without a finished eval run; None: none.
    missing: str | None = None


@dataclass
class Table:
    """A report table: display strings for Markdown/LaTeX, numbers for CSV; a caption line (the
    agent) under its title and footnotes under it, in every format."""

    name: str
    title: str
    shown: pd.DataFrame
    numbers: pd.DataFrame
    notes: list[str] = field(default_factory=list)
    caption: str = ""

    def markdown(self) -> str:
        cols = list(self.shown.columns)
        lines = [f"**{self.title}**", ""]
        if self.caption:
            lines += [f"*{self.caption}*", ""]
        lines += [
            "| " + " | ".join(_md(c) for c in cols) + " |",
            "|" + "|".join("---" for _ in cols) + "|",
        ]
        for _, row in self.shown.iterrows():
            lines.append("| " + " | ".join(_md(str(row[c])) for c in cols) + " |")
        for note in self.notes:
            lines += ["", note]
        return "\n".join(lines) + "\n"

    def latex(self) -> str:
        cols = list(self.shown.columns)
        spec = "l" + "c" * (len(cols) - 1)
        body = [" & ".join(_tex(c) for c in cols) + r" \\", r"\midrule"]
        for _, row in self.shown.iterrows():
            body.append(" & ".join(_tex(str(row[c])) for c in cols) + r" \\")
        caption = _tex(self.title) + (f". {_tex(self.caption)}" if self.caption else "")
        notes = []
        if self.notes:
            text = r"\par ".join(_tex(n) for n in self.notes)
            notes = [r"  \par\smallskip", "  {\\footnotesize " + text + "}"]
        return "\n".join(
            [
                r"\begin{table}[h]",
                r"  \centering",
                f"  \\caption{{{caption}}}",
                f"  \\begin{{tabular}}{{{spec}}}",
                r"    \toprule",
                *("    " + b for b in body),
                r"    \bottomrule",
                r"  \end{tabular}",
                *notes,
                r"\end{table}",
                "",
            ]
        )

    def html(self) -> str:
        head = "".join(f"<th>{_html(c)}</th>" for c in self.shown.columns)
        rows = "".join(
            "<tr>" + "".join(f"<td>{_html(str(v))}</td>" for v in row) + "</tr>"
            for row in self.shown.itertuples(index=False)
        )
        caption = f"<p class='agent'>{_html(self.caption)}</p>" if self.caption else ""
        notes = "".join(f"<p class='note'>{_html(n)}</p>" for n in self.notes)
        return (
            f"<h3 id='{self.name}'>{_html(self.title)}</h3>{caption}<table><thead><tr>{head}"
            f"</tr></thead><tbody>{rows}</tbody></table>{notes}"
        )

    def write(self, folder: Path) -> list[Path]:
        paths = [folder / f"{self.name}.{ext}" for ext in ("md", "tex", "csv")]
        paths[0].write_text(self.markdown())
        paths[1].write_text(self.latex())
        self.numbers.to_csv(paths[2], index=False, float_format="%.10g")
        return paths


def _md(text: str) -> str:
    return str(text).replace("|", "\\|")


#: Characters LaTeX needs spelled out (text mode, T1/OT1 fonts).
_TEX = {
    "\\": r"\textbackslash{}",
    "&": r"\&",
    "%": r"\%",
    "_": r"\_",
    "#": r"\#",
    "$": r"\$",
    "{": r"\{",
    "}": r"\}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "|": r"$|$",
    "<": r"$<$",
    ">": r"$>$",
    "±": r"$\pm$",
    "–": "--",
    "—": "---",
    "−": r"$-$",
    "π": r"$\pi$",
    "τ": r"$\tau$",
    "γ": r"$\gamma$",
    "≤": r"$\leq$",
    "≥": r"$\geq$",
    "×": r"$\times$",
    "·": r"$\cdot$",
    "‖": r"$\|$",
    "†": r"\textsuperscript{\dag}",
    "‡": r"\textsuperscript{\ddag}",
    "→": r"$\to$",
    "α": r"$\alpha$",
    "ᾱ": r"$\bar{\alpha}$",
    "ρ": r"$\rho$",
    "§": r"\S{}",
    "“": "``",
    "”": "''",
    "≈": r"$\approx$",
    "²": r"\textsuperscript{2}",
}
_TEX_PATTERN = re.compile("q\u0307|" + "|".join(re.escape(c) for c in _TEX))


def _tex(text: str) -> str:
    return _TEX_PATTERN.sub(
        lambda m: r"$\dot{q}$" if m.group(0) == "q\u0307" else _TEX[m.group(0)], str(text)
    )


def _html(text: str) -> str:
    return str(text).replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


# --------------------------------------------------------------------------- tables I and II
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


#: Table II as printed in the paper, by config key.
PAPER_TABLE_II: dict[str, Any] = {
    "velocity_bound": [0.1, 0.4],
    "batch_size": 512,
    "tau": 0.001,
    "buffer_size": 1_000_000,
    "learning_starts": 1000,
    "gamma": 0.995,
    "episodes": 20000,
    "action_period": 0.03,
    "max_steps": 1000,
    "learning_rate": 0.001,
}


def table_two(train_cfg: dict[str, Any], agents: Sequence[AgentInfo] = ()) -> Table:
    """Agent parameters as used, beside the paper's: the preset, its algorithm and learning aids
    (whether any uses privileged knowledge), the algorithm's settings (the shared ones it does not
    read shown as "–"; its own after them), and the budget configured and spent.

    ``agents``: the selection's train runs (the first is the one whose config is ``train_cfg``);
    none: the aids are read from ``train_cfg`` and the budget spent is not known.
    """
    agent, env, robot = train_cfg["agent"], train_cfg["env"], train_cfg["robot"]
    paper = PAPER_TABLE_II
    algo = str(agent.get("algo") or "sac")
    infos = list(agents) or [
        AgentInfo(
            "", str(agent.get("name", "?")), aids_of(agent, train_cfg.get("train") or {}),
            algo=algo,
        )
    ]  # fmt: skip
    title = TITLES.get(algo, algo)
    left_out = set(infos[0].left_out)

    def used(key: str, value: Any) -> Any:
        return f"– (not {title}'s)" if key in left_out else value

    def bounds(values: Sequence[float]) -> str:
        return ", ".join(f"q̇{j + 1}: [−{b:g}, +{b:g}]" for j, b in enumerate(values))

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
    lr = _plain(agent["learning_rate"])
    if agent.get("lr_final") is not None:
        lr += f" → {_plain(agent['lr_final'])} (linear over the budget)"
    budget = f"{_plain(agent['episodes'])} episodes of ≤ {_plain(env['max_steps'])} steps"
    if agent.get("max_env_steps") is not None:
        budget += f", ≤ {int(agent['max_env_steps']):,} env steps"
    if agent.get("max_minutes") is not None:
        budget += f", ≤ {float(agent['max_minutes']):g} min wall time"

    def spent(key: str, show: Any, scale: float = 1.0) -> str:
        values = [i.spent[key] * scale for i in infos if math.isfinite(i.spent.get(key, math.nan))]
        if not values:
            return "not logged"
        if len(values) == 1:
            return str(show(values[0]))
        mean = sum(values) / len(values)
        return f"{show(mean)} (mean of {len(values)} runs, {show(min(values))}–{show(max(values))})"

    steps = spent("env_steps", lambda v: f"{v:,.0f}")
    if any(i.spent.get("demo_steps", 0) > 0 for i in infos):
        demo = spent("demo_steps", lambda v: f"{v:,.0f}")
        steps += f" (+ {demo} in planner demonstrations)"
    stopped = ", ".join(dict.fromkeys(i.stop_reason for i in infos if i.stop_reason))
    unfinished = sorted({i.status for i in infos if i.known and i.status != "FINISHED"})
    if unfinished:
        stopped = (stopped + "; " if stopped else "") + (
            f"{'/'.join(unfinished)} run: last values logged while training"
        )
    nets = "×".join(str(int(u)) for u in agent.get("net_arch", []))
    if agent.get("critic_arch"):
        nets = f"actor {nets}, critics " + "×".join(str(int(u)) for u in agent["critic_arch"])
    rows: list[tuple[str, Any, Any]] = [
        ("Preset", ", ".join(dict.fromkeys(i.preset for i in infos)), "plain SAC"),
        ("Algorithm", ", ".join(dict.fromkeys(i.algorithm for i in infos)), "SAC"),
        ("Learning aids", aids, "none"),
        ("Aided", aided, "no"),
        (
            "Velocity bounds (rad/s)",
            bounds(robot["velocity_bound"]),
            bounds(paper["velocity_bound"]),
        ),
        *[
            (label, used(key, agent[key]), paper[key])
            for label, key in (
                ("Batch size", "batch_size"),
                ("Target smoothing factor", "tau"),
                ("Experience buffer length", "buffer_size"),
                ("Initial random steps", "learning_starts"),
            )
        ],
        ("Discount factor", agent["gamma"], paper["gamma"]),
        ("Time step (s)", env["action_period"], paper["action_period"]),
        ("Max time steps/episode", env["max_steps"], paper["max_steps"]),
        ("Learning rate", lr, paper["learning_rate"]),
        ("n-step returns", used("n_steps", agent.get("n_steps", 1)), "–"),
        ("Hidden layers", nets or "–", "–"),
        ("Parallel environments", agent.get("n_envs", 1), "–"),
        (
            "Gradient steps per update",
            used(
                "gradient_steps",
                f"{_plain(agent['gradient_steps'])} every {_plain(agent['train_freq'])} step(s)",
            ),
            "–",
        ),
        ("Gradients", agent.get("gradients", "autograd"), "–"),
        *_own_options(agent, algo, title),
        (
            "Training budget",
            budget,
            f"{paper['episodes']} episodes of ≤ {paper['max_steps']} steps",
        ),
        ("Env steps used", steps, "–"),
        ("Episodes used", spent("episodes", lambda v: f"{v:,.0f}"), "–"),
        ("Wall time used (min)", spent("wall_s", lambda v: f"{v:.1f}", 1 / 60), "–"),
        ("Stopped on", stopped or "not logged", "–"),
    ]
    shown = pd.DataFrame(
        [(k, _plain(v), _plain(p)) for k, v, p in rows], columns=["Parameter", "Value", "Paper"]
    )
    source = infos[0].train_run
    notes = [
        "Value: the train run's resolved config"
        + (f" (train run {source})" if source else "")
        + "; used: its final metrics"
        + (f", over the {len(infos)} train runs of the selection" if len(infos) > 1 else "")
        + ". Paper: its Table II (– where it gives no value). Aided: a learning aid uses "
        "privileged knowledge of the planner or the obstacles, which the paper's model-free "
        "SAC does not have."
    ]
    return Table(
        "table2_agent",
        "Table II: DRL agent parameters as used",
        shown,
        shown.copy(),
        notes,
        caption=caption(infos),
    )


def _own_options(agent: dict[str, Any], algo: str, title: str) -> list[tuple[str, Any, Any]]:
    """Table II rows of the options only ``algo`` has (its ``agent.<algo>`` section), and the
    entropy temperature where the algorithm has one."""
    rows: list[tuple[str, Any, Any]] = []
    if algo in ("sac", "tqc", "crossq"):
        rows.append(("Entropy coefficient", agent.get("ent_coef", "auto"), "–"))
    own = agent.get(algo)
    if isinstance(own, dict):
        rows += [(f"{title}: {key}", value, "–") for key, value in own.items()]
    return rows


def _params_table(name: str, title: str, rows: list[tuple[str, Any]]) -> Table:
    shown = pd.DataFrame([(k, _plain(v)) for k, v in rows], columns=["Parameter", "Value"])
    return Table(name, title, shown, shown.copy())


def _plain(v: Any) -> str:
    if isinstance(v, float) and v.is_integer() and abs(v) >= 1:
        return str(int(v))
    return str(v)
