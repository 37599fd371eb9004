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
from armexp.config import compose_config
from armexp.stages.pipeline import tune_steps
from tests.helpers import interrupt_training_at, stage_runs

README = Path(__file__).resolve().parents[1] / "README.md"
TUNE = ["tuner.n_iterations=2", "tuner.n_nests=4", "tuner.objective.n_scenarios=2",
        "tuner.objective.horizon=0.2"]  # fmt: skip
TRAIN = ["agent.max_env_steps=300", "agent.learning_starts=100", "agent.net_arch=[32,32]",
         "env.max_steps=100", "train.progress=false"]  # fmt: skip
#: A plain row of `experiment=reproduce` at TRAIN's agent budget (its update eager: no compile).
_ROW_BUDGET = [
    o.removeprefix("agent.").replace("=", ":", 1) for o in TRAIN if o.startswith("agent.")
]
PLAIN_ROW = "{" + ",".join([*_ROW_BUDGET, "gradients:autograd"]) + "}"
#: Appended to each stage's examples: the smallest budgets that still run every part.
TINY = {
    "simulate": ["scenario.duration=0.1"],
    "tune": [*TUNE, "tune.progress=false"],
    "train": TRAIN,
    "eval": ["eval.animations=false"],
    "report": [],
    "hpo": [
        "agent.max_env_steps=200",
        "train.eval_every=100",
        "train.eval_targets=2",
        "env.max_steps=50",
    ],
    "pipeline": [
        *TUNE,
        *TRAIN,
        "tune.progress=false",
        "pipeline.seeds=[0,1]",
        "tasks.n_random=2",
        "eval.animations=false",
    ],
}


def commands(after: str = "") -> list[str]:
    """The command lines, without comments, of the first bash block after ``after`` in the
    README."""
    text = README.read_text()
    block = text[text.index(after) :].split("```bash\n", 1)[1].split("```", 1)[0]
    lines = [line.split("  #")[0].strip() for line in block.splitlines()]
    return [line for line in lines if line and not line.startswith("#")]


def examples(after: str = "Examples:\n\n") -> list[str]:
    """The armexp lines of the first bash block after ``after`` in the README."""
    return [line for line in commands(after) if line.startswith("armexp ")]


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
    # Every tune run a default eval reads: each baseline's and the adaptive references'.
    for controller, criterion in tune_steps(compose_config([])).values():
        tune = ["tune", f"controller={controller}", f"tuner.objective.criterion={criterion}"]
        assert main([*tune, *TUNE, *where]) == 0
    commands = examples(after="## Sweeps")
    assert len(commands) >= 4
    for line in commands:
        stage = line.split()[1]
        extra = [*TINY[stage], *where]
        if stage == "pipeline":
            extra.remove("pipeline.seeds=[0,1]")  # the sweep gives the seeds
        if stage == "eval":
            extra.append("tasks.n_random=1")
        if "quick" in line:
            extra.append("agent.aids.demonstrations.episodes=20")  # sac_quick plans 1000
        _shell(" ".join([line, *(f"'{o}'" for o in extra)]), tmp_path)


@pytest.mark.slow  # two minutes: every Examples line, a study included
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
        if stage in ("train", "pipeline") and ("quick" in line or "reproduce" in line):
            extra.append("agent.aids.demonstrations.episodes=20")  # sac_quick plans 1000
        if stage == "report":
            extra.append(f"report.out_dir={tmp_path / 'report'}")
        if "reproduce" in line:  # its agents' rows train 1 M steps at the study's seeds
            extra.append(
                f"pipeline.agents=[{{preset:sac_plain_red_n10,seeds:[0],agent:{PLAIN_ROW}}}]"
            )
        _shell(" ".join([line, *(f"'{o}'" for o in extra)]), tmp_path)


def _ui_block() -> list[str]:
    """The command lines of the bash block in the README's UI section."""
    return commands(after="## Looking at runs")


@pytest.mark.long
@pytest.mark.parametrize(
    "which",
    # The plain MLflow line serves the same store as `armexp ui`; it is slow (about 25 s).
    [pytest.param(0, id="armexp ui"), pytest.param(1, id="mlflow ui", marks=pytest.mark.slow)],
)
def test_the_ui_commands_serve_the_stores_runs_and_stop_on_ctrl_c(
    tmp_path: Path, which: int
) -> None:
    """Both lines of the UI block serve the runs in ``runs/`` (the port moved off 5000 so tests
    can run side by side); Ctrl-C stops the server and leaves every run as it was."""
    import json
    import signal
    import socket
    import time
    import urllib.request

    assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                 f"tracking.runs_dir={tmp_path / 'runs'}"]) == 0  # fmt: skip
    (sim,) = stage_runs(tmp_path / "runs", "simulate")
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    line = _ui_block()[which]
    assert line.split()[:2] == (["armexp", "ui"] if which == 0 else ["mlflow", "ui"])
    line += f" ui.port={port}" if which == 0 else f" --port {port}"
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    proc = subprocess.Popen(
        ["bash", "-c", f"exec {line}"],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
        # Ctrl-C's default action even where this test runs with SIGINT ignored (a background
        # job), as a terminal would give.
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    url = f"http://127.0.0.1:{port}/ajax-api/2.0/mlflow/runs/search"
    try:
        for _ in range(120):
            try:
                body = json.dumps({"experiment_ids": [sim.info.experiment_id]}).encode()
                request = urllib.request.Request(url, body, {"Content-Type": "application/json"})
                with urllib.request.urlopen(request, timeout=2) as res:
                    listed = json.load(res)["runs"]
                break
            except OSError:
                assert proc.poll() is None, proc.stdout.read() if proc.stdout else ""
                time.sleep(0.5)
        else:
            pytest.fail("the UI did not answer within 60 s")
        assert [r["info"]["run_id"] for r in listed] == [sim.info.run_id]
        # Marked classic ML, the kind MLflow's UI opens on the runs table.
        query = f"experiments/get?experiment_id={sim.info.experiment_id}"
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/ajax-api/2.0/mlflow/{query}") as res:
            tags = {t["key"]: t["value"] for t in json.load(res)["experiment"]["tags"]}
        assert tags["mlflow.experimentKind"] == "custom_model_development"
    finally:
        os.killpg(proc.pid, signal.SIGINT)
        out, _ = proc.communicate(timeout=60)
    if which == 0:  # MLflow's own line runs 4 workers, which may print their import cut short
        assert "Traceback" not in out, out[-3000:]
        assert "Warning" not in out, out[-3000:]
        # The link opens the experiment's runs table in the UI's "Machine learning" view.
        link = f"/#/experiments/{sim.info.experiment_id}/runs?workflowType=machine_learning"
        assert f"open http://127.0.0.1:{port}{link}" in out, out[-3000:]
    (after,) = stage_runs(tmp_path / "runs", "simulate")
    assert after.info.status == "FINISHED"
    assert stage_runs(tmp_path / "runs", "ui") == []  # serving the UI is not a run


def test_ci_runs_the_readmes_test_line_and_both_lines_install_quietly() -> None:
    """`.ci/run` is the README's second line on a fresh clone; both set-up lines pass ``-q`` to
    pip, so the first one's output is armexp's own summary lines (one screen)."""
    first, second = commands()
    ci = (README.parent / ".ci" / "run").read_text().strip().splitlines()[-1]
    assert ci == second
    for line in (first, second):
        assert "pip install -q -c constraints.txt " in line
    assert "armexp pipeline experiment=demo" in first
