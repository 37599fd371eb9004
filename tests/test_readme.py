"""Every command of the README's Examples block runs as written, through a real shell, with tiny
budgets appended (and placeholders such as ``<run id>`` filled with runs made before it), so
the manual cannot rot."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from armexp.cli import main
from tests.helpers import interrupt_training_at, stage_runs

README = Path(__file__).resolve().parents[1] / "README.md"
TUNE = ["tuner.n_iterations=2", "tuner.n_nests=4", "tuner.objective.n_scenarios=2",
        "tuner.objective.horizon=0.2"]  # fmt: skip
TRAIN = ["agent.max_env_steps=300", "agent.learning_starts=100", "agent.net_arch=[32,32]",
         "env.max_steps=100", "train.progress=false", "agent.demonstrations=20"]  # fmt: skip
#: Appended to each stage's examples: the smallest budgets that still run every part.
TINY = {
    "simulate": ["scenario.duration=0.1"],
    "tune": [*TUNE, "tune.progress=false"],
    "train": TRAIN,
    "eval": [],
    "report": [],
    "pipeline": [*TUNE, *TRAIN, "tune.progress=false", "pipeline.seeds=[0,1]", "tasks.n_random=2"],
}


def examples(after: str = "Examples:\n\n") -> list[str]:
    """The armexp lines of the first bash block after ``after`` in the README."""
    text = README.read_text()
    block = text.split(after, 1)[1].split("```bash\n", 1)[1].split("```", 1)[0]
    lines = [line.split("  #")[0].strip() for line in block.splitlines()]
    return [line for line in lines if line.startswith("armexp ")]


def _shell(command: str, cwd: Path) -> None:
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", "-c", command], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=900)  # fmt: skip
    assert done.returncode == 0, (command, done.stderr[-3000:])


@pytest.mark.slow
def test_every_sweep_example_runs_as_written(tmp_path: Path) -> None:
    """The Sweeps section's block: basic, joblib and parallel launchers, tiny budgets."""
    where = [f"tracking.runs_dir={tmp_path / 'runs'}"]
    assert main(["train", "controller.gains=paper", "agent=sac_smoke", *TRAIN, *where]) == 0
    assert main(["tune", "controller=pid", *TUNE, *where]) == 0  # eval's PID gains
    commands = examples(after="## Sweeps")
    assert len(commands) >= 4
    for line in commands:
        stage = line.split()[1]
        extra = [*TINY[stage], *where]
        if stage == "pipeline":
            extra.remove("pipeline.seeds=[0,1]")  # the sweep gives the seeds
        if stage == "eval":
            extra.append("tasks.n_random=1")
        _shell(" ".join([line, *(f"'{o}'" for o in extra)]), tmp_path)


def test_every_example_runs_as_written(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    runs = tmp_path / "runs"
    where = [f"tracking.runs_dir={runs}"]
    # A KILLED train run for the resume example.
    interrupt_training_at(monkeypatch, 250)
    killed = ["train", "controller.gains=paper", "agent=sac_smoke", "train.checkpoint_every=100",
              *TRAIN, *where]  # fmt: skip
    assert main(killed) == 130
    monkeypatch.undo()
    (stopped,) = stage_runs(runs, "train")
    commands = examples()
    assert len(commands) >= 10
    for line in commands:
        stage = line.split()[1]
        evals = [r.info.run_id for r in stage_runs(runs, "eval")] if "<id>" in line else []
        line = line.replace("<run id>", stopped.info.run_id)
        if evals:
            line = re.sub(r"<id>,<id>", ",".join((evals * 2)[:2]), line)
        # A resume keeps its run's own budget (and refuses other overrides).
        extra = [*([] if "train.resume=" in line else TINY[stage]), *where]
        if stage == "report":
            extra.append(f"report.out_dir={tmp_path / 'report'}")
        _shell(" ".join([line, *(f"'{o}'" for o in extra)]), tmp_path)
