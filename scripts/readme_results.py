"""Copy a report's summary into the README's results section (between its markers).

    python scripts/readme_results.py runs/report            # the report folder of a study

The section is replaced by ``tables/summary.md`` of that report (per agent and baseline: held-out
success and the two verdicts; whether adaptation contributes), its claim check
(``tables/claim_check.md``: one two-sided verdict per claim and baseline, with the CIs and what
they cover), the commands that made and regenerate it, and the ids of the runs it was made from,
so the README's numbers always come from a stored report, never from hand-written prose.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

import pandas as pd

START, END = "<!-- results:start -->", "<!-- results:end -->"


def _claims(report: Path) -> str:
    """The claim check's table without its agent caption (the summary's says it)."""
    text = (report / "tables" / "claim_check.md").read_text().strip()
    return re.sub(r"^(\*\*[^\n]*\*\*)\n\n\*[^\n]*\*\n", r"\1\n", text)


def section(report: Path, source: str) -> str:
    summary = (report / "tables" / "summary.md").read_text().strip()
    # The summary's own title line is the section's heading already.
    summary = re.sub(r"^\*\*Summary\*\*\s*", "", summary)
    try:
        claims = pd.read_csv(report / "tables" / "claim_check.csv")
    except pd.errors.EmptyDataError:  # no baseline was run: an empty table
        claims = pd.DataFrame()
    if len(claims) and "baseline" not in claims.columns:
        raise ValueError(
            f"{report} is a report made before the claim check named its baselines; make the "
            "report again with this armexp."
        )
    runs = pd.read_csv(report / "runs.csv")
    evals = runs[runs.stage == "eval"]
    lines = [
        START,
        f"{source} Regenerate the report with the command at the end of its `index.html`.",
        "",
        summary,
        "",
        _claims(report),
        "",
        f"Eval runs ({len(evals)}): " + ", ".join(f"`{r}`" for r in evals.run_id) + ".",
        END,
    ]
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path, help="a report folder (with tables/summary.md)")
    parser.add_argument("--readme", type=Path, default=Path("README.md"))
    parser.add_argument(
        "--source", default="From `armexp pipeline experiment=reproduce`.", help="what made it"
    )
    args = parser.parse_args()
    text = args.readme.read_text()
    if START not in text or END not in text:
        print(f"{args.readme} has no {START} … {END} section", file=sys.stderr)
        return 2
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    try:
        text = section(args.report, args.source)
    except ValueError as exc:
        print(exc, file=sys.stderr)
        return 2
    args.readme.write_text(head + text + tail)
    print(f"{args.readme}: results section replaced from {args.report}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
