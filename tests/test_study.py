"""A study (`pipeline.seeds`): one child pipeline per seed, one report over the seeds, a failed
seed named as missing, and a re-run that finishes it by reusing the finished seeds."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from armexp.cli import main
from tests.helpers import SMALL_TRAIN, pid_baseline, stage_runs

SMALL = [
    "experiment=smoke",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
    *SMALL_TRAIN,
    "eval.animations=false",  # the renderer has its own tests
    "tasks.n_random=2",
    "tuner.seed=${seed}",
    "pipeline.seeds=[0,1,2]",
    "pipeline.paper_gains_row=true",
    "train.eval_every=300",
    "train.eval_targets=2",
    f"eval.baselines=[{pid_baseline()}]",
]


@pytest.mark.slow  # two studies of two seeds each: about 35 s
def test_a_study_with_a_failed_seed_reports_the_others_and_is_finished_by_a_rerun(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    from armexp.stages import train

    runs = tmp_path / "runs"
    real = train.run

    def crashes_on_seed_1(cfg: Any) -> Any:
        if int(cfg.seed) == 1:
            raise RuntimeError("out of memory (injected)")
        return real(cfg)

    monkeypatch.setattr(train, "run", crashes_on_seed_1)
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 0
    out = capsys.readouterr().out
    assert "study: seed 1 failed (RuntimeError: out of memory (injected))" in out
    pipelines = stage_runs(runs, "pipeline", newest_first=False)
    study = pipelines[0]
    assert study.data.tags["armexp.study"] == "0,1,2"
    assert study.data.tags["armexp.failed_seeds"] == "1"
    assert study.info.status == "FINISHED"
    seeds = {p.data.params["seed"]: p for p in pipelines[1:]}
    assert seeds["1"].info.status == "FAILED" and seeds["0"].info.status == "FINISHED"
    assert all(p.data.tags["mlflow.parentRunId"] == study.info.run_id for p in pipelines[1:])
    # Each seed tunes with its own seed: different CSO draws, different gains.
    tunes = [r for r in stage_runs(runs, "tune") if r.data.params["controller.name"] == "pid"]
    assert sorted(r.data.params["tuner.seed"] for r in tunes) == ["0", "1", "2"]
    evals = stage_runs(runs, "eval")
    assert len(evals) == 4  # seeds 0 and 2: tuned gains (with the baseline) and paper gains
    assert sorted(e.data.tags["armexp.adaptive_gains"] for e in evals) == [
        "config", "config", "tuned", "tuned",
    ]  # fmt: skip

    tables = runs / "report" / "tables"
    table3 = pd.read_csv(tables / "table3_performance.csv")
    for column in ("tip_rms_cm", "tip_rms_cm_ci_low", "tip_rms_cm_ci_high", "tip_rms_cm_n"):
        assert column in table3.columns
    ours = table3[(table3.controller == "adaptive") & ~table3.agent.str.contains("paper gains")]
    assert set(ours.tip_rms_cm_n) == {2} and (ours.tip_rms_cm_ci_low <= ours.tip_rms_cm).all()
    assert table3.agent.str.contains("paper gains").any()
    claims = pd.read_csv(tables / "claim_check.csv")
    assert len(claims) == 2 * claims.baseline.nunique() >= 2  # each claim against each baseline
    assert claims.verdict.notna().all() and set(claims.seeds) == {2}
    missing = "Missing: seed 1 of 3 has no finished eval run"
    for name in ("table3_performance.md", "comparison_controllers.md", "claim_check.md"):
        assert missing in (tables / name).read_text(), name
    assert missing in (runs / "report" / "index.html").read_text()
    for figure in ("performance_profiles", "learning_curves"):
        assert (runs / "report" / "figures" / f"{figure}.png").exists(), figure

    # The same command again, without the fault: seeds 0 and 2 are reused, seed 1 runs.
    monkeypatch.setattr(train, "run", real)
    trains = len(stage_runs(runs, "train"))
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 0
    assert len(stage_runs(runs, "train")) == trains + 1
    again = stage_runs(runs, "pipeline")[0]  # the newest: seed 2 of the re-run
    assert again.data.params["seed"] == "2" and "armexp.reused.train" in again.data.tags
    assert "Missing" not in (tables / "claim_check.md").read_text()
    assert len(pd.read_csv(runs / "report" / "runs.csv").query("stage == 'eval'")) == 6


@pytest.mark.slow
def test_a_report_mixing_robots_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    where = f"tracking.runs_dir={runs}"
    common = ["experiment=smoke", *SMALL_TRAIN, "train.gains=config", where]
    evals = []
    for robot in ("two_link_paper", "three_link"):
        assert main(["train", f"robot={robot}", *common]) == 0
        assert main(["eval", f"robot={robot}", "eval.baselines=[]", "eval.ablation=false",
                     "tasks.n_random=0", where]) == 0  # fmt: skip
        evals.append(stage_runs(runs, "eval")[0].info.run_id)
    capsys.readouterr()
    assert main(["report", f"report.eval_runs=[{','.join(evals)}]", where]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "report.eval_runs mixes robot settings, which is not allowed" in err[0]
    assert "two_link_paper" in err[0] and "three_link" in err[0]
