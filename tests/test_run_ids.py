"""Run ids as armexp prints them: every key that takes a run id, and ``armexp diff``, take a unique
prefix of one (as git takes a commit's); an ambiguous prefix names its candidates, an unknown one
says so, both in one sentence with exit code 2 and no run started."""

from __future__ import annotations

import uuid
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.config import compose_config
from armexp.tracking import stage_runs

A = "abcd0000" + "0" * 23 + "1"
B = "abcd0000" + "0" * 23 + "2"
C = "ef01" + "0" * 28


@pytest.fixture
def three_runs(runs_dir: Path, monkeypatch: pytest.MonkeyPatch) -> MlflowClient:
    """A store with train runs A and B, which share their first 30 hex digits, and tune run C."""
    experiment = stage_runs.setup(compose_config([f"tracking.runs_dir={runs_dir}"]))
    client = MlflowClient(f"sqlite:///{runs_dir}/mlflow.db")
    for run_id, stage in ((A, "train"), (B, "train"), (C, "tune")):
        with monkeypatch.context() as m:
            m.setattr(uuid, "uuid4", lambda rid=run_id: uuid.UUID(hex=rid))
            run = client.create_run(experiment, tags={"armexp.stage": stage})
        assert run.info.run_id == run_id
        client.set_terminated(run_id, "FINISHED")
    return client


def _runs(client: MlflowClient) -> int:
    return len(client.search_runs([e.experiment_id for e in client.search_experiments()]))


KEYS = [
    ("eval", "eval.train_run"),
    ("play", "play.train_run"),
    ("train", "train.tune_run"),
    ("train", "train.resume"),
    ("report", "report.pipeline_run"),
    ("eval", "eval.tune_runs.pid_itae"),
    ("play", "play.tune_runs.computed_torque"),
]


@pytest.mark.long
@pytest.mark.parametrize(("stage", "key"), KEYS)
def test_an_ambiguous_prefix_names_its_candidates(
    stage: str, key: str, three_runs: MlflowClient, runs_dir: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    assert main([stage, f"{key}=abcd0000", f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"armexp {stage}: {key}=abcd0000 is not allowed: it begins 2 run ids, {A} (train) and "
        f"{B} (train); give more of the id."
    ]
    assert _runs(three_runs) == 3


@pytest.mark.long
@pytest.mark.parametrize(("stage", "key"), KEYS)
def test_an_unknown_prefix_is_one_sentence(
    stage: str, key: str, three_runs: MlflowClient, runs_dir: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:  # fmt: skip
    assert main([stage, f"{key}=9999abcd", f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"armexp {stage}: {key}=9999abcd is not allowed: no run id in the store "
        f"sqlite:///{runs_dir}/mlflow.db begins with 9999abcd."
    ]
    assert _runs(three_runs) == 3


@pytest.mark.long
def test_a_list_of_eval_runs_takes_prefixes(
    three_runs: MlflowClient, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["report", "report.eval_runs=[ef01,abcd]", where]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(
        "armexp report: report.eval_runs contains abcd, which is not allowed: it begins 2 run ids"
    )
    # A unique prefix is taken; C is then refused for what it is, under its full id.
    assert main(["report", "report.eval_runs=[ef01]", where]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"armexp report: report.eval_runs contains {C}, which is not allowed: it is a tune run, "
        "not an eval run."
    ]


def test_a_prefix_too_short_or_not_hex_is_one_sentence(
    three_runs: MlflowClient, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    for value in ("abc", "latest"):
        assert main(["eval", f"eval.train_run={value}", f"tracking.runs_dir={runs_dir}"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [
            f"armexp eval: eval.train_run={value} is not allowed: a run id is 32 hex digits, or "
            "a prefix of at least 4 of them (as armexp prints them)."
        ]


@pytest.mark.long
def test_diff_takes_prefixes(
    three_runs: MlflowClient, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["diff", A, "ef01", where]) == 0
    assert capsys.readouterr().out.startswith(f"armexp diff: A {A} vs B {C}")
    assert main(["diff", "abcd0000", "ef01", where]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        f"armexp diff: run id abcd0000 is not allowed: it begins 2 run ids, {A} (train) and "
        f"{B} (train); give more of the id."
    ]


@pytest.mark.parametrize("prefix", ["606274e9", "12345678", "1e5a"])
def test_a_prefix_that_reads_as_a_number_stays_the_text_typed(prefix: str) -> None:
    cfg = compose_config([f"eval.train_run={prefix}", f"eval.tune_runs.pid_itae={prefix}",
                          f"report.eval_runs=[{prefix},abcd1234]"])  # fmt: skip
    assert cfg.eval.train_run == prefix and cfg.eval.tune_runs.pid_itae == prefix
    assert list(cfg.report.eval_runs) == [prefix, "abcd1234"]
