"""armexp report: tables and figures from a store written by short real runs, MLflow only."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any, cast

import matplotlib.pyplot as plt
import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.report.figures import learning_curves
from tests.helpers import log_run, run_without

FIGURES = (
    "fig3_tip_paths",
    "fig4_target_error",
    "fig5_torques",
    "fig6_tracking",
    "training_curves",
    "performance_profiles",
    "cso_convergence",
)
TABLES = (
    "summary",
    "table1_environment",
    "table2_agent",
    "table3_performance",
    "comparison_controllers",
    "claim_check",
    "tuning_spread",
    "cso_gains",
)


def _report(store: Path, out: Path) -> int:
    return main(["report", f"tracking.runs_dir={store}", f"report.out_dir={out}"])


@pytest.mark.long
def test_report_has_every_table_and_figure(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert _report(store, out) == 0
    table3 = pd.read_csv(out / "tables" / "table3_performance.csv")
    for controller in ("adaptive", "paper"):  # Table III: the proposed control and the paper
        assert sorted(table3[table3.controller == controller].task) == ["a", "b", "c", "d"]
    markdown = (out / "tables" / "table3_performance.md").read_text()
    for task in "abcd":
        assert f"| ({task}) | proposed |" in markdown and f"| ({task}) | paper |" in markdown
    # Every controller the eval ran is in the comparison, and each baseline in the claim check.
    compared = pd.read_csv(out / "tables" / "comparison_controllers.csv")
    assert compared.label.iloc[0] == "adaptive" and (compared.role == "baseline").any()
    checked = pd.read_csv(out / "tables" / "claim_check.csv")
    assert set(checked.baseline) == set(compared.label[compared.role == "baseline"])
    for name in TABLES:
        for ext in ("md", "tex", "csv"):
            assert (out / "tables" / f"{name}.{ext}").stat().st_size > 0, (name, ext)
    assert r"\toprule" in (out / "tables" / "table1_environment.tex").read_text()
    for name in FIGURES:
        png = (out / "figures" / f"{name}.png").read_bytes()
        pdf = (out / "figures" / f"{name}.pdf").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 5000, name
        assert pdf.startswith(b"%PDF") and len(pdf) > 1000, name
    index = (out / "index.html").read_text()
    for name in FIGURES:
        assert f"figures/{name}.png" in index
    client = MlflowClient(f"sqlite:///{store}/mlflow.db")
    (ev,) = client.search_runs(
        [client.get_experiment_by_name("armexp").experiment_id],  # type: ignore[union-attr]
        "tags.`armexp.stage` = 'eval'",
    )
    assert ev.info.run_id in index and "armexp report" in index
    # The page opens with what ran and how it did, linked to the runs in the MLflow UI.
    glance = index.split("<h2>At a glance</h2>", 1)[1].split("</ul>", 1)[0]
    ui = "http://127.0.0.1:5000/#/experiments"
    assert f"{ui}/{ev.info.experiment_id}/runs/{ev.info.run_id}" in glance
    assert "held-out success" in glance and "convergence claim <i>" in glance
    assert "Gains tuned by cuckoo search in: pid, " in glance
    assert index.index("At a glance") < index.index("<h2>Tables</h2>")
    # The report run carries the folder as an artifact.
    (rep,) = client.search_runs(
        [ev.info.experiment_id],
        "tags.`armexp.stage` = 'report'",
        order_by=["attributes.start_time DESC"],
        max_results=1,
    )
    assert rep.info.status == "FINISHED"
    names = {f.path for f in client.list_artifacts(rep.info.run_id, "report/tables")}
    assert "report/tables/table3_performance.md" in names


@pytest.mark.long
def test_report_shows_the_eval_runs_animations(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert _report(store, out) == 0
    index = (out / "index.html").read_text()
    assert "<h2>Animations</h2>" in index
    shown = sorted({part.split("/")[0] for part in index.split("src='animations/")[1:]})
    baselines = pd.read_csv(out / "tables" / "comparison_controllers.csv").label
    assert "adaptive" in shown and set(shown) <= set(baselines) and len(shown) >= 2
    for label in shown:
        for task in "abcd":
            gif, mp4 = f"animations/{label}/{task}.gif", f"animations/{label}/{task}.mp4"
            assert f"<img src='{gif}'" in index and f"<a href='{mp4}'>MP4</a>" in index
            assert (out / gif).read_bytes().startswith(b"GIF89a")
            assert (out / mp4).read_bytes()[4:8] == b"ftyp"


@pytest.mark.slow
def test_report_twice_gives_identical_tables(store: Path, tmp_path: Path) -> None:
    assert _report(store, tmp_path / "one") == 0
    assert _report(store, tmp_path / "two") == 0
    for name in TABLES:
        for ext in ("md", "tex", "csv"):
            first = (tmp_path / "one" / "tables" / f"{name}.{ext}").read_bytes()
            second = (tmp_path / "two" / "tables" / f"{name}.{ext}").read_bytes()
            assert first == second, (name, ext)


@pytest.mark.slow
def test_report_runs_without_simulation_environment_or_agent_code(
    store: Path, tmp_path: Path
) -> None:
    blocked = [
        "armexp.sim",
        "armexp.envs",
        "armexp.agents",
        "armexp.tune",
        "stable_baselines3",
        "gymnasium",
        "torch",
        "numba",
    ]
    code = (
        "from armexp.cli import main\n"
        f"sys.exit(main(['report', 'tracking.runs_dir={store}', 'report.out_dir={tmp_path}/r']))\n"
    )
    res = run_without(blocked, code, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "r" / "tables" / "table3_performance.md").exists()


@pytest.mark.long
def test_empty_store_is_one_sentence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", f"tracking.runs_dir={tmp_path / 'runs'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "armexp eval" in err


@pytest.mark.long
def test_selection_without_eval_runs_is_one_sentence(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["report", f"tracking.runs_dir={store}", "report.filter=\"tags.sweep = 'none'\""])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no FINISHED eval run" in err


# ------------------------------------------------- stores logged by hand: what tables must say
def _episode(
    controller: str,
    task: str,
    reached: bool = True,
    tracking: float = 1.0,
    error: float = 2.0,
    convergence: float = 0.02,
) -> dict[str, object]:
    return {
        "controller": controller,
        "task": task,
        "reason": "reached" if reached else "truncated",
        "target_x": 1.0,
        "target_y": 0.5,
        "success": float(reached),
        "collision": 0.0,
        "target_time": 5.0 if reached else math.nan,
        "final_error_cm": error,
        "rms_e1": 0.001,
        "tip_rms_cm": tracking,
        "max_abs_tau_1": 312.0,
        "max_abs_tau_2": 145.0,
        "time_at_limit": 0.25,
        "convergence_time": convergence,
        "steps": 100.0,
        "return": -10.0,
        "duration": 3.0,
    }


#: (a) both reach, the proposed controller's convergence is 0 (a ratio against zero);
#: (b) PID does not reach; (c) the proposed never settles and PID's target error is 0;
#: (d) convergence comes from the eval run's metrics (0.015 and inf), not episodes.csv.
HAND_EPISODES = [
    _episode("adaptive", "a", tracking=0.8, error=2.0, convergence=0.0),
    _episode("pid", "a", tracking=1.0, error=2.5, convergence=0.019),
    _episode("adaptive", "b", convergence=0.012),
    _episode("pid", "b", reached=False, convergence=0.03),
    _episode("adaptive", "c", convergence=math.inf),
    _episode("pid", "c", error=0.0, convergence=0.03),
    _episode("adaptive", "d", convergence=0.5),
    _episode("pid", "d", convergence=0.02),
    _episode("adaptive", "random_000"),
    _episode("pid", "random_000", reached=False),
]


def _hand_store(runs: Path, agent: str) -> tuple[str, str]:
    """A train run of preset ``agent`` and an eval run of its policy, logged through MLflow as
    the stages log them (no stage runs): returns (train run id, eval run id)."""
    from omegaconf import OmegaConf

    from armexp.config import compose_config
    from armexp.tracking import stage_runs

    train_cfg = compose_config([f"agent={agent}", f"tracking.runs_dir={runs}"])
    experiment_id = stage_runs.setup(train_cfg)
    train_id = log_run(
        experiment_id,
        "train",
        stage_runs.flatten(train_cfg),
        tags={"armexp.stop_reason": "time"},
        metrics={
            "final/env_steps": 123456.0,
            "final/episodes": 789.0,
            "final/wall_s": 1230.0,
            "demonstrations/steps": 45678.0,
        },
        texts={"config.yaml": OmegaConf.to_yaml(train_cfg, resolve=True)},
    )
    # The eval run's own config composes the default agent (sac_paper): the report must name
    # the policy's preset from the train run, not this.
    eval_params = stage_runs.flatten(compose_config([f"tracking.runs_dir={runs}"]))
    eval_params.update({"eval.initial_offset": "0.05", "robot.torque_limit": "[400.0, 300.0]"})
    episodes = pd.DataFrame(HAND_EPISODES).to_csv(index=False)
    eval_id = log_run(
        experiment_id,
        "eval",
        eval_params,
        tags={"armexp.train_run": train_id},
        metrics={"adaptive.d.convergence_time": 0.015, "pid.d.convergence_time": math.inf},
        texts={"episodes.csv": episodes},
    )
    return train_id, eval_id


@pytest.fixture(scope="module")
def hand_reports(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """Reports of two hand-logged stores: an aided preset (sac_quick) and the plain one."""
    out = {}
    for agent in ("sac_quick", "sac_paper"):
        runs = tmp_path_factory.mktemp(agent) / "runs"
        _, eval_id = _hand_store(runs, agent)
        folder = runs.parent / "report"
        rc = main(
            [
                "report",
                f"tracking.runs_dir={runs}",
                f"report.out_dir={folder}",
                f"report.eval_runs=[{eval_id}]",
            ]
        )
        assert rc == 0
        out[agent] = folder
    return out


def _text(folder: Path, name: str, ext: str) -> str:
    return (folder / "tables" / f"{name}.{ext}").read_text()


def _row(markdown: str, start: str) -> list[str]:
    (line,) = [line for line in markdown.splitlines() if line.startswith(start)]
    return [cell.strip() for cell in line.strip("|").split(" | ")]


@pytest.mark.slow
def test_an_aided_run_is_reported_without_agent_code(
    hand_reports: dict[str, Path], tmp_path: Path
) -> None:
    # The aids' declarations are plain data (armexp.aids): naming them imports no add-on.
    runs = hand_reports["sac_quick"].parent / "runs"
    blocked = ["armexp.sim", "armexp.envs", "armexp.agents", "armexp.tune", "torch"]
    code = (
        "from armexp.cli import main\n"
        f"sys.exit(main(['report', 'tracking.runs_dir={runs}', 'report.out_dir={tmp_path}/r']))\n"
    )
    res = run_without(blocked, code, cwd=tmp_path)
    assert res.returncode == 0, res.stderr[-3000:]
    table = _text(tmp_path / "r", "table2_agent", "md")
    assert table == _text(hand_reports["sac_quick"], "table2_agent", "md")
    assert "| Aided | yes: demonstrations, behaviour cloning, DAgger expert" in table


def test_table_two_names_the_preset_its_aids_and_the_budget_spent(
    hand_reports: dict[str, Path],
) -> None:
    md = _text(hand_reports["sac_quick"], "table2_agent", "md")
    assert _row(md, "| Preset |")[1] == "sac_quick"
    aids = _row(md, "| Learning aids |")[1]
    for aid in ("1000 planner demonstrations", "behaviour cloning", "DAgger", "averaged"):
        assert aid in aids, aid
    assert _row(md, "| Aided |")[1].startswith("yes: demonstrations, behaviour cloning")
    budget = _row(md, "| Training budget |")[1]
    assert "≤ 400,000 env steps" in budget and "≤ 60 min wall time" in budget
    assert _row(md, "| Env steps used |")[1] == "123,456 (+ 45,678 in planner demonstrations)"
    assert _row(md, "| Episodes used |")[1] == "789"
    assert _row(md, "| Wall time used (min) |")[1] == "20.5"
    assert _row(md, "| Stopped on |")[1] == "time"
    assert _row(md, "| Batch size |")[1:] == ["256", "512"]  # as used, beside the paper's
    csv = pd.read_csv(hand_reports["sac_quick"] / "tables" / "table2_agent.csv")
    assert csv.set_index("Parameter").loc["Preset", "Value"] == "sac_quick"
    plain = _text(hand_reports["sac_paper"], "table2_agent", "md")
    assert _row(plain, "| Preset |")[1] == "sac_paper"
    assert _row(plain, "| Learning aids |")[1] == "none"
    assert _row(plain, "| Aided |")[1] == "no"


def test_table_three_and_the_pid_comparison_say_when_the_agent_is_aided(
    hand_reports: dict[str, Path],
) -> None:
    aided = "sac_quick (aided: demonstrations, behaviour cloning, DAgger expert"
    for agent, says in (("sac_quick", aided), ("sac_paper", "sac_paper (plain SAC")):
        folder = hand_reports[agent]
        for name in ("table3_performance", "comparison_controllers"):
            md = _text(folder, name, "md")
            caption = md.splitlines()[2]
            assert caption.startswith("*Agent: ") and says in caption, (agent, name, caption)
            assert ("aided:" in caption) == (agent == "sac_quick")
            assert ("not the paper's plain SAC" in caption) == (agent == "sac_quick")
            tex = _text(folder, name, "tex")
            assert says.replace("_", r"\_") in tex.split(r"\caption{")[1].split("\n")[0]
            csv = pd.read_csv(folder / "tables" / f"{name}.csv")
            ours = csv[csv.agent.notna()]
            assert len(ours) and (ours.aided == (agent == "sac_quick")).all()
            assert ours.agent.str.startswith(agent).all()
        plain_missing = "The paper's plain SAC is not among the selected runs"
        assert (plain_missing in _text(folder, "table3_performance", "md")) == (
            agent == "sac_quick"
        )
        index = (folder / "index.html").read_text()
        assert index.count(says) >= 3  # page header, Table III, comparison
        runs = pd.read_csv(folder / "runs.csv")
        assert set(runs.agent) == {agent}  # eval runs named by their policy's preset


def test_the_papers_target_error_keeps_its_printed_units_with_a_note(
    hand_reports: dict[str, Path],
) -> None:
    folder = hand_reports["sac_quick"]
    md = _text(folder, "table3_performance", "md")
    assert _row(md, "| (a) | paper |")[4] == "0.025 cm†"
    note = "labelled cm, but 0.025–0.039 cm"
    assert note in md and "read as metres (2.5–3.9 cm)" in md
    assert "labelled cm, but 0.025--0.039 cm" in _text(folder, "table3_performance", "tex")
    assert note in (folder / "index.html").read_text()


def test_old_eval_runs_read_as_adaptive_against_pid_gaing(hand_reports: dict[str, Path]) -> None:
    """An eval run made before controllers.yaml (labels adaptive and pid, no Definition-1
    measures) still makes every table: pid is reported as pid_gaing, tuned under the paper's
    criterion, and the convergence claim is "–"."""
    folder = hand_reports["sac_quick"]
    compared = pd.read_csv(folder / "tables" / "comparison_controllers.csv").set_index("label")
    assert list(compared.index) == ["adaptive", "pid_gaing"]
    assert list(compared.role) == ["proposed", "baseline"]
    assert list(compared.criterion) == ["gaing", "gaing"] and list(compared.horizon) == [0.6, 0.6]
    md = _text(folder, "comparison_controllers", "md")
    header = _row(md, "| Label |")
    pid = dict(zip(header, _row(md, "| pid_gaing |"), strict=True))
    assert pid["Tuned under"] == "gaing over 0.6 s" and pid["Compared with"] == "adaptive"
    assert pid["Decay rate α (1/s)"] == "–" and pid["Tip RMS (cm)"] == "1.000"
    assert pid["Held-out success"] == "0.0 % of 1"
    claims = pd.read_csv(folder / "tables" / "claim_check.csv").set_index("claim")
    assert set(claims.baseline) == {"pid_gaing"} and set(claims.proposed) == {"adaptive"}
    assert claims.loc["faster convergence", "verdict"] == "–"
    assert claims.loc["better accuracy", "verdict"] == "none (needs ≥ 2 seeds)"
    assert "made before the Definition-1 measures" in _text(folder, "claim_check", "md")
    summary = _text(folder, "summary", "md")
    assert "| pid_gaing (pid, gaing over 0.6 s) |" in summary
    for name in ("comparison_controllers", "claim_check", "summary", "table3_performance"):
        text = _text(folder, name, "md").lower()
        for bad in ("+100.0 %", "| inf", "nan"):
            assert bad not in text, (name, bad)
    index = (folder / "index.html").read_text()
    assert "against <b>pid_gaing (pid, gaing over 0.6 s)</b>" in index


def test_convergence_prints_finite_times_and_a_dash_when_never_settled(
    hand_reports: dict[str, Path],
) -> None:
    """Old eval runs: Table III keeps their run-subtraction column (labelled as such), the
    Definition-1 columns are "–"."""
    md = _text(hand_reports["sac_quick"], "table3_performance", "md")
    header = _row(md, "| Task |")
    column = header.index("Run subtraction (s)")
    assert _row(md, "| (b) | proposed |")[column] == "0.012"
    assert _row(md, "| (c) | proposed |")[column] == "–"  # episodes.csv: inf
    assert _row(md, "| (d) | proposed |")[column] == "0.015"  # the metric, not the csv's 0.5
    assert "| (d) | PID |" not in md and "| (d) | paper |" in md
    assert _row(md, "| (a) | proposed |")[header.index("Decay rate α (1/s)‡")] == "–"
    assert _row(md, "| (a) | paper |")[header.index("Settling time (s)‡")] == (
        "0.01 (optimization time)"
    )
    assert "Run subtraction: eval runs made before the Definition-1 measures" in md
    assert "after an initial reference offset of 0.05 rad on every joint" in md
    torque = header.index("Max torque τ1 / τ2 (N·m)")
    assert _row(md, "| (a) | proposed |")[torque] == "312.0 / 145.0"
    assert _row(md, "| (a) | proposed |")[header.index("Time at limit (s)")] == "0.250"
    assert "Torque limit: ±400, ±300 N·m" in md


def test_several_agents_are_told_apart_not_averaged_together() -> None:
    from armexp.report import comparison, performance

    rows = []
    for agent, preset, aided, tracking in (
        ("sac_quick (aided: demonstrations)", "sac_quick", True, 0.5),
        ("sac_paper (plain SAC, no learning aids)", "sac_paper", False, 2.0),
    ):
        for controller in ("adaptive", "pid"):
            episode = _episode(controller, "a", tracking=tracking)
            rows.append({**episode, "eval_run": preset, "agent": agent,
                         "agent_preset": preset, "aided": aided})  # fmt: skip
    episodes = pd.DataFrame(rows)
    table = performance.table_three(episodes)
    proposed = table.shown[table.shown.Control == "proposed"]
    assert list(proposed.Agent) == ["sac_quick (aided)", "sac_paper (plain)"]
    assert list(proposed["Tracking error (cm)"]) == ["0.500", "2.000"]
    compared = comparison.comparison(episodes)
    assert set(compared.shown.Agent) == {"sac_quick (aided)", "sac_paper (plain)"}
    assert list(compared.shown.Label) == ["adaptive", "pid_gaing"] * 2


def test_only_aids_with_privileged_knowledge_make_an_agent_aided() -> None:
    from armexp.report.agent import AgentInfo, aids_of

    # Runs stored before aids were composed from agent.aids set them with agent keys.
    plainish = aids_of({"relabel": 0.5, "average_tail": 0.25, "clearance": 0.03, "n_steps": 5})
    assert [a.name for a in plainish] == [
        "hindsight relabelling",
        "collision clearance",
        "weight averaging",
    ]
    info = AgentInfo("t", "custom", plainish)
    assert not info.aided and "without privileged knowledge" in info.label
    shaped = aids_of({"shaping": 30.0})
    assert AgentInfo("t", "custom", shaped).aided
    # Aids composed from agent.aids: the known ones by name and detail, others by target.
    from omegaconf import OmegaConf

    from armexp.config import compose_config

    agent = OmegaConf.to_container(compose_config(["agent=sac_quick"]).agent)
    assert isinstance(agent, dict)
    quick = aids_of(cast(dict[str, Any], agent))  # a config's keys are names
    assert [(a.name, a.privileged) for a in quick] == [
        ("demonstrations", True), ("behaviour cloning", True), ("DAgger expert", True),
        ("weight averaging", False),
    ]  # fmt: skip
    assert quick[0].detail == "1000 planner demonstrations in the replay buffer"
    assert quick[3].detail == "final actor averaged over the last 25 % of the budget"
    addons = aids_of({"aids": {"x": {"_target_": "armexp.agents.expert.ExpertLabels"}}})
    assert [(a.name, a.privileged) for a in addons] == [("ExpertLabels", True)]
    assert AgentInfo("t", "sac_paper", []).label == "sac_paper (plain SAC, no learning aids)"


def test_a_train_run_without_its_config_names_its_aids_from_its_params() -> None:
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from armexp.config import compose_config
    from armexp.report.agent import agent_info, aids_of
    from armexp.tracking import stage_runs

    cfg = compose_config(["agent=sac_quick"])
    run = SimpleNamespace(
        data=SimpleNamespace(params=stage_runs.flatten(cfg), tags={}, metrics={}),
        info=SimpleNamespace(status="FINISHED"),
    )
    from_params = agent_info("t", cast(Any, run), None)
    agent = OmegaConf.to_container(cfg.agent)
    assert isinstance(agent, dict)
    assert from_params.aids == aids_of(cast(dict[str, Any], agent)) and from_params.aided
    assert [a.name for a in from_params.aids][:2] == ["demonstrations", "behaviour cloning"]
    # An aid stored by its preset name without a _target_ is read by that name.
    (named,) = aids_of({"aids": {"averaging": {"tail": 0.5}}})
    assert (named.name, named.privileged) == ("weight averaging", False)
    assert named.detail == "final actor averaged over the last 50 % of the budget"


def test_each_aid_is_declared_once_and_its_add_on_and_the_presets_point_at_it() -> None:
    import importlib

    from armexp import aids
    from armexp.agents.addons import TrainingAddOn
    from armexp.config import compose_config

    for preset in ("sac_quick", "sac_demo"):
        specs = compose_config([f"agent={preset}"]).agent.aids
        assert {name: spec._target_ for name, spec in specs.items()} == {
            a.name: a.target
            for a in aids.AIDS
            if a
            not in (
                aids.PRETRAINING,
                aids.CURRICULUM,
                aids.MISSED_TARGETS,
                aids.RANDOM_STARTS,
                aids.HER,
                aids.COLOURED_NOISE,
                aids.SELF_IMITATION,
                aids.COUNT_BONUS,
                aids.LIMIT_GUARD,
                aids.LATE_PHASE,
            )
        }, preset
    for declaration in aids.AIDS:
        module, _, name = declaration.target.rpartition(".")
        addon = getattr(importlib.import_module(module), name)
        assert issubclass(addon, TrainingAddOn) and addon.declaration is declaration
        assert aids.declared(declaration.name) is aids.declared(declaration.target) is declaration
    assert {a.name: a.privileged for a in aids.AIDS} == {
        "demonstrations": True, "cloning": True, "pretraining": True, "expert": True,
        "averaging": False, "curriculum": False, "missed_targets": False, "random_starts": False,
        "her": False, "coloured_noise": False, "self_imitation": False, "count_bonus": False,
        "limit_guard": False, "late_phase": False,
    }  # fmt: skip
    assert aids.declared("armexp.agents.expert.ExpertLabels") is None
    assert aids.privileged_modules() == (
        "armexp.agents.demonstrations", "armexp.agents.cloning", "armexp.agents.pretraining",
        "armexp.agents.expert",
    )  # fmt: skip


@pytest.mark.long
def test_out_dir_that_is_not_a_report_is_refused_and_left_as_it_was(
    store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = tmp_path / "d"
    folder.mkdir()
    (folder / "keep").write_text("x")
    assert _report(store, folder) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"report.out_dir={folder} is not allowed" in err[0]
    assert (folder / "keep").read_text() == "x" and sorted(p.name for p in folder.iterdir()) == [
        "keep"
    ]


@pytest.mark.slow
def test_a_failing_report_keeps_the_previous_one(
    store: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from armexp.report import page

    out = tmp_path / "report"
    assert _report(store, out) == 0
    before = (out / "tables" / "table3_performance.md").read_text()

    def broken(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("disk full (injected)")

    monkeypatch.setattr(page.figures, "tip_paths", broken)
    assert _report(store, out) == 1
    assert (out / "tables" / "table3_performance.md").read_text() == before
    assert (out / ".armexp-report").exists()
    leftovers = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert leftovers == []
    monkeypatch.undo()
    assert _report(store, out) == 0  # an earlier report's folder is replaced


@pytest.mark.slow
def test_the_readmes_filter_example_runs_as_written(store: Path, tmp_path: Path) -> None:
    """The README's report.filter line, through a real shell (its quoting is the point)."""

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    (line,) = [
        line.split("#")[0].strip()
        for line in readme.splitlines()
        if line.startswith('armexp report "report.filter=')
    ]
    command = f"{line} tracking.runs_dir={store} report.out_dir={tmp_path / 'r'}"

    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(
        ["bash", "-c", command], capture_output=True, text=True, timeout=300, env=env
    )
    assert done.returncode == 0, done.stderr
    assert "eval runs matching params.seed = '0'" in done.stdout


def test_learning_curves_without_finished_episodes_say_so_instead_of_an_empty_legend() -> None:
    reward = pd.DataFrame({"step": [10, 20], "value": [-3.0, -2.5]})
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # matplotlib's "No artists with labels" among them
        fig = learning_curves({"sac_smoke": {"reward": reward}})
    top, bottom = fig.axes
    assert top.get_legend() is None
    assert [t.get_text() for t in top.texts] == ["no finished episodes or held-out checks"]
    assert len(bottom.lines) == 1
    success = pd.DataFrame({"step": [10, 20], "value": [0.0, 0.5]})
    with_episodes = learning_curves({"sac_smoke": {"reward": reward, "success": success}})
    assert with_episodes.axes[0].get_legend() is not None and not with_episodes.axes[0].texts
    plt.close(fig)
    plt.close(with_episodes)
