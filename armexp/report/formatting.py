"""What every report table shares: the `Table` it is written through (Markdown, LaTeX,
HTML, CSV), the `Context` it says beside its numbers, and the formatting of its cells: numbers,
percentages, and IQM [95 % CI] cells over runs (`armexp.report.stats`, `N_BOOT` resamples,
fixed so a report is reproducible). A non-finite value is shown as "–" (docs/design.md §9).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from armexp.report import stats

#: Bootstrap resamples of every CI in the report.
N_BOOT = 2000


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


# --------------------------------------------------------------------------- cells
def number(value: float, digits: int = 3) -> str:
    """``digits`` decimals, or significant digits below 0.01; "–" when not finite."""
    if not math.isfinite(value):
        return "–"
    if abs(value) < 1e-2 and value != 0:
        return f"{value:.{digits}g}"
    return f"{value:.{digits}f}"


def iqm_cell(values: np.ndarray, digits: int = 3) -> tuple[str, dict[str, float]]:
    """ "IQM [low, high]" of one value per run (just the value for one run), and the numbers."""
    v = values[np.isfinite(values)]
    if v.size == 0:
        return "–", {"iqm": math.nan, "ci_low": math.nan, "ci_high": math.nan, "n": 0}
    if v.size == 1:
        return number(float(v[0]), digits), {
            "iqm": float(v[0]), "ci_low": math.nan, "ci_high": math.nan, "n": 1,
        }  # fmt: skip
    point, low, high = stats.iqm_ci(v, n_boot=N_BOOT)
    text = f"{number(point, digits)} [{number(low, digits)}, {number(high, digits)}]"
    return text, {"iqm": point, "ci_low": low, "ci_high": high, "n": int(v.size)}


def pct(x: float) -> str:
    """A share as a signed percentage ("+12.3 %"); "–" when not finite."""
    return f"{100 * x:+.1f} %" if math.isfinite(x) else "–"


def plain(v: Any) -> str:
    """A config value as shown: a whole float without its ".0"."""
    if isinstance(v, float) and v.is_integer() and abs(v) >= 1:
        return str(int(v))
    return str(v)


def column(rows: pd.DataFrame, key: str) -> np.ndarray:
    return rows[key].to_numpy(dtype=float) if key in rows.columns else np.zeros(0)


def cell(rows: pd.DataFrame, key: str, numbers: dict[str, Any], digits: int = 3) -> str:
    """IQM [CI] of one column over the runs; the numbers go into ``numbers`` (the CSV row)."""
    text, got = iqm_cell(column(rows, key), digits)
    numbers.update({key: got["iqm"], f"{key}_ci_low": got["ci_low"],
                    f"{key}_ci_high": got["ci_high"], f"{key}_n": got["n"]})  # fmt: skip
    return text


def statistics_note(n_runs: int, n_seeds: int) -> str:
    if n_runs <= 1:
        return "One eval run: each cell is that run's value."
    return (
        f"IQM [95 % CI]: interquartile mean over each row's eval runs (one per seed; {n_runs} "
        f"runs, {n_seeds} seeds selected) with a percentile stratified bootstrap CI, {N_BOOT} "
        "resamples (Agarwal et al., NeurIPS 2021); a single run shows its value."
    )


PLAIN_MISSING = (
    "The paper's plain SAC is not among the selected runs: add the eval runs of a plain preset "
    "(e.g. sac_paper) to report.eval_runs to show it beside the aided agent."
)


def context_notes(ctx: Context) -> list[str]:
    notes = []
    if ctx.missing:
        notes.append(ctx.missing)
    if ctx.plain_missing:
        notes.append(PLAIN_MISSING)
    return notes
