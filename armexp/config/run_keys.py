"""The config keys that take run ids, and their values kept as text.

Hydra's override grammar reads a bare ``606274e9`` as the float 6.06274e14 and ``12345678`` as an
integer, so an 8-character id as armexp prints it would reach the config as a number;
`quote_ids` quotes the bare hex values of these keys before Hydra parses them.
"""

from __future__ import annotations

import re

#: Keys whose value is one run id.
SINGLE = ("train.tune_run", "train.resume", "eval.train_run", "play.train_run",
          "report.pipeline_run", "tracking.sweep_run")  # fmt: skip
#: Keys whose value is a list of run ids.
LISTS = ("report.eval_runs", "report.hpo_runs")
#: Keys whose value maps labels to run ids (``eval.tune_runs.pid_itae=<id>``).
MAPS = ("eval.tune_runs", "play.tune_runs")
KEYS = (*SINGLE, *LISTS, *MAPS)

_BARE_HEX = re.compile(r"[0-9a-fA-F]+")


def takes_ids(key: str) -> bool:
    """Whether the override key ``key`` (``+``/``~`` prefixes allowed) takes run ids."""
    name = key.lstrip("+~")
    return name in KEYS or name.startswith(tuple(f"{k}." for k in MAPS))


def quote_ids(value: str) -> str:
    """``value`` with each bare hex item (alone, in a ``[…]`` list or a sweep's ``a,b``) quoted."""
    inner, wrap = (value[1:-1], "[{}]") if value[:1] == "[" and value[-1:] == "]" else (value, "{}")
    items = [f"'{v}'" if _BARE_HEX.fullmatch(v.strip()) else v for v in inner.split(",")]
    return wrap.format(",".join(items))
