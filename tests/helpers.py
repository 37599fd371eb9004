"""Shared budgets and look-ups for tests that run real stages (seconds, not minutes)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import pandas as pd
    import pytest

SMALL_TUNE = [
    "tuner=cso_fast",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
]
# 600 steps of a small SAC with 100-step episodes: it learns nothing, it exercises everything.
SMALL_TRAIN = [
    "agent=sac_smoke",
    "agent.max_env_steps=600",
    "agent.learning_starts=100",
    "agent.net_arch=[32,32]",
    "train.checkpoint_every=200",
    "train.progress=false",
    "env.max_steps=100",
]


def plain_train(runs_dir: Path, *overrides: str) -> list[str]:
    """`armexp train` arguments for ``SMALL_TRAIN`` as a non-privileged preset with the paper's
    gains, stored under ``runs_dir``, with ``overrides`` (an aid, say) after them."""
    return ["train", *SMALL_TRAIN, "agent.privileged=false", "train.gains=config",
            "controller.gains=paper", *overrides, f"tracking.runs_dir={runs_dir}"]  # fmt: skip


def refused_in_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], argv: list[str], *words: str
) -> None:
    """`armexp` with ``argv`` exits 2 with one line on stderr holding each of ``words``, and the
    store under ``runs_dir`` gains no train run."""
    from armexp.cli import main

    before = len(stage_runs(runs_dir, "train"))
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and all(word in err for word in words), err
    assert len(stage_runs(runs_dir, "train")) == before


def row_at(frame: pd.DataFrame, key: tuple[Any, ...]) -> pd.Series:
    """The row of ``frame`` at ``key`` on its MultiIndex: pandas-stubs types
    ``frame.loc[(a, b)]`` as the cell at row a, column b."""
    import pandas as pd

    row = frame.loc[key]
    assert isinstance(row, pd.Series), key
    return row


def pid_baseline() -> str:
    """The PID baseline tuned under the default criterion (``pid_itae``): the one a plain
    ``armexp tune controller=pid`` run serves."""
    from armexp.config import compose_config
    from armexp.gains import criterion_of

    return f"pid_{criterion_of(compose_config([]))}"


def logged_tune_run(cfg: Any, gains_yaml: str) -> str:
    """A FINISHED tune run of ``cfg`` (its params: controller, robot, criterion…) whose
    ``gains.yaml`` is ``gains_yaml``, without tuning: for tests of what reads tune runs."""
    import mlflow

    from armexp.tracking import stage_runs

    with stage_runs.stage_run(cfg, "tune") as run:
        mlflow.log_text(gains_yaml, "gains.yaml")
    return str(run.info.run_id)


def existing_store_client(store: Any) -> Any:
    """An `MlflowClient` of a store that exists: a runs folder (SQLite) or a URI. MlflowClient
    creates a missing SQLite store in place, migrating its schema; a test polling a store that
    an armexp process it started is about to create would race that process's own creation
    (seen: "table guardrails already exists"). A missing one raises FileNotFoundError instead,
    which polling loops wait out; armexp puts a new store in place whole (`new_store.make`)."""
    from mlflow.tracking import MlflowClient

    uri = store if isinstance(store, str) else f"sqlite:///{store}/mlflow.db"
    if uri.startswith("sqlite:///") and not Path(uri[len("sqlite:///") :]).is_file():
        raise FileNotFoundError(f"no MLflow store at {uri} yet")
    return MlflowClient(uri)


def stage_runs(store: Any, stage: str, newest_first: bool = True) -> list[Any]:
    """The runs of one stage in experiment 'armexp' of a store: a runs folder (SQLite) or a URI."""
    client = existing_store_client(store)
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None, f"no experiment 'armexp' in {client.tracking_uri}"
    order = "DESC" if newest_first else "ASC"
    return client.search_runs(
        [exp.experiment_id],
        f"tags.`armexp.stage` = '{stage}'",
        order_by=[f"attributes.start_time {order}"],
    )


def small_sac(settings: Any, n_envs: int = 1, batch_size: int = 64) -> Any:
    """`sac_quick`'s SAC on ``n_envs`` environments of ``settings``, with SB3's logger set up as
    `learn` would (for tests that drive its updates or callbacks directly)."""
    from stable_baselines3.common.logger import Logger

    from armexp.agents.sac import build_sac
    from armexp.agents.vec import make_vec_env
    from armexp.config import compose_config

    overrides = ["agent=sac_quick", "agent.gradients=autograd",  # no compilation in tests
                 f"agent.n_envs={n_envs}", f"agent.batch_size={batch_size}"]  # fmt: skip
    agent = compose_config(overrides).agent
    model = build_sac(agent, make_vec_env(settings, n_envs, "dummy", 0), 0)
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def interrupt_training_at(monkeypatch: Any, steps: int) -> None:
    """Make training raise KeyboardInterrupt (as Ctrl-C) once it reaches ``steps`` environment
    steps; ``monkeypatch.undo()`` or the test's end restores it."""
    from armexp.agents.callbacks import EpisodeStats

    original = EpisodeStats._on_step

    def interrupted(self: EpisodeStats) -> bool:
        if self.num_timesteps >= steps:
            raise KeyboardInterrupt
        return original(self)

    monkeypatch.setattr(EpisodeStats, "_on_step", interrupted)


def stop_and_resume(
    runs_dir: Path, monkeypatch: Any, capsys: Any, argv: list[str], at: int
) -> tuple[Any, Any]:
    """Runs `armexp` with ``argv``, stopped as by Ctrl-C at ``at`` environment steps (exit 130),
    then ``train.resume`` of the run it left, which must say it continues from ``at`` with its
    replay buffer and finish; the stopped run as it was left, and the resumed one."""
    from armexp.cli import main

    interrupt_training_at(monkeypatch, at)
    assert main(argv) == 130
    (stopped,) = stage_runs(runs_dir, "train")
    assert stopped.info.status == "KILLED"
    monkeypatch.undo()
    capsys.readouterr()
    resume = [f"train.resume={stopped.info.run_id}", f"tracking.runs_dir={runs_dir}"]
    assert main(["train", *resume]) == 0
    assert f"from step {at}, with its replay buffer" in capsys.readouterr().out
    (resumed,) = stage_runs(runs_dir, "train")
    assert resumed.info.status == "FINISHED"
    return stopped, resumed


def config_dir_with_my_arm(tmp_path: Path) -> Path:
    """A config folder for ``--config-dir`` with one extra robot option, ``robot=my_arm`` (the
    paper arm under another name)."""
    from armexp.config import config_dir

    extra = tmp_path / "my_conf" / "robot"
    extra.mkdir(parents=True)
    text = (config_dir() / "robot" / "two_link_paper.yaml").read_text()
    (extra / "my_arm.yaml").write_text(text.replace("name: two_link_paper", "name: my_arm"))
    return extra.parent


def run_without(blocked: list[str], code: str, cwd: Path | None = None) -> Any:
    """Run ``code`` in a fresh interpreter where importing any of ``blocked`` (packages or
    modules, with their submodules) fails as if it were not installed. A finder raises, rather
    than a None entry in sys.modules, because libraries that probe sys.modules trip on that."""
    import os
    import subprocess
    import sys

    script = (
        "import sys\n"
        "class Block:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        f"        if any(name == b or name.startswith(b + '.') for b in {blocked!r}):\n"
        "            raise ModuleNotFoundError(name)\n"
        "sys.meta_path.insert(0, Block())\n" + code
    )
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          cwd=cwd, env={**os.environ})  # fmt: skip


# ------------------------------------------------------------ report: runs logged by hand
def log_run(
    experiment_id: str,
    stage: str,
    params: dict[str, str],
    tags: dict[str, str] | None = None,
    metrics: dict[str, float] | None = None,
    texts: dict[str, str] | None = None,
    frames: dict[str, Any] | None = None,
) -> str:
    """One run logged through MLflow as a stage logs it (tag ``armexp.stage``), without running
    the stage: params, tags, metrics, text artifacts and Parquet artifacts (``frames``: artifact
    path → DataFrame). Returns its id."""
    import tempfile

    import mlflow

    with mlflow.start_run(
        experiment_id=experiment_id, tags={"armexp.stage": stage, **(tags or {})}
    ) as run:
        items = sorted(params.items())
        for i in range(0, len(items), 100):
            mlflow.log_params(dict(items[i : i + 100]))
        if metrics:
            mlflow.log_metrics(metrics)
        for name, text in (texts or {}).items():
            mlflow.log_text(text, name)
        with tempfile.TemporaryDirectory() as folder:
            for name, frame in (frames or {}).items():
                path = Path(folder) / Path(name).name
                frame.to_parquet(path)
                mlflow.log_artifact(str(path), str(Path(name).parent))
        return str(run.info.run_id)
