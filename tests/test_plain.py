"""The non-privileged agent and Table II's SAC at speed (docs/plain_agent.md): every agent preset
trains through the train stage; ``sac_plain`` uses no planner or obstacle knowledge and a
privileged aid added to it is refused; ``sac_paper_fast`` keeps every Table II value and Table II
lists what it changes as not aided; ``experiment=reproduce`` runs the plain rows beside its aided
agent."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any, cast

import pytest
from omegaconf import OmegaConf

from armexp import aids, paper
from armexp.cli import main
from armexp.config import compose_config, config_dir
from armexp.report.tables import changes, table_two
from tests.helpers import stage_runs

PRESETS = sorted(p.stem for p in (config_dir() / "agent").glob("*.yaml"))
NON_PRIVILEGED = ["sac_paper", "sac_paper_fast", "sac_plain", "sac_plain_red", "sac_plain_red_n10",
                  "crossq_plain_red_n10", "sac_plain_red_n10_sil",
                  "sac_plain_red_n10_count", "sac_plain_red_n10_g998",
                  "sac_plain_guard", "sac_plain_guard_g996",
                  "crossq_plain_guard_g996", "crossq_plain_guard_g996_missed",
                  "crossq_plain_guard_g998_utd1", "crossq_plain_guard_late"]  # fmt: skip
#: Small enough for seconds: tiny networks and batches, 100-step episodes, 300 steps. The
#: eager update, because compiling the update takes a minute (tests/test_compiled_update.py
#: covers it).
TINY = ["train.gains=config", "controller.gains=paper", "train.progress=false",
        "env.max_steps=100", "agent.max_env_steps=300", "agent.max_minutes=null",
        "agent.learning_starts=100", "agent.batch_size=32", "agent.net_arch=[32,32]",
        "agent.gradients=autograd", "agent.ppo.n_steps=32", "agent.tqc.n_quantiles=5",
        "agent.buffer_size=5000"]  # fmt: skip
#: Table II's values as agent keys.
TABLE_II_AGENT = ("batch_size", "tau", "buffer_size", "learning_starts", "gamma",
                  "learning_rate", "episodes")  # fmt: skip


def _tiny(preset: str) -> list[str]:
    """`TINY` for ``preset``, with the options only some presets have made small too."""
    agent = compose_config([f"agent={preset}"]).agent
    out = [f"agent={preset}", *TINY]
    if agent.critic_arch is not None:
        out.append("agent.critic_arch=[32,32]")
    if "demonstrations" in agent.aids:
        out.append("agent.aids.demonstrations.episodes=4")
    return out


# ------------------------------------------------------------------------ every preset trains
@pytest.mark.long
@pytest.mark.parametrize("preset", PRESETS)
def test_every_agent_preset_trains_a_few_hundred_steps_through_the_train_stage(
    preset: str, runs_dir: Path
) -> None:
    assert main(["train", *_tiny(preset), f"tracking.runs_dir={runs_dir}"]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.info.status == "FINISHED"
    assert run.data.tags["armexp.agent_preset"] == preset
    assert 300 <= run.data.metrics["final/env_steps"] < 300 + 256  # one rollout past at most


# ------------------------------------------------------------------------- the plain preset
@pytest.mark.long
def test_the_non_privileged_presets_are_marked_and_carry_only_unprivileged_aids() -> None:
    with_aids = set()
    for preset in NON_PRIVILEGED:
        agent = compose_config([f"agent={preset}"]).agent
        assert agent.privileged is False, preset
        for aid in agent.aids.values():
            declaration = aids.declared(str(aid._target_))
            assert declaration is not None and not declaration.privileged, preset
            with_aids.add(preset)
    # sac_plain_red is sac_plain plus red exploration noise, sac_plain_red_n10 that with 10-step
    # returns, crossq_plain_red_n10 that with CrossQ's own (eager) update, the _sil and _count
    # presets and sac_plain_guard that with one more aid each, _g998 that with gamma 0.998,
    # sac_plain_guard_g996 the guarded one at gamma 0.996, crossq_plain_guard_g996 that with
    # CrossQ, crossq_plain_guard_g996_missed that with the missed_targets aid,
    # crossq_plain_guard_g998_utd1 that at gamma 0.998 and one update per step,
    # crossq_plain_guard_late the missed_targets one with the late_phase aid; the others carry
    # no aid.
    assert with_aids == {"sac_plain_red", "sac_plain_red_n10", "crossq_plain_red_n10",
                         "sac_plain_red_n10_sil", "sac_plain_red_n10_count",
                         "sac_plain_red_n10_g998", "sac_plain_guard",
                         "sac_plain_guard_g996", "crossq_plain_guard_g996",
                         "crossq_plain_guard_g996_missed",
                         "crossq_plain_guard_g998_utd1", "crossq_plain_guard_late"}  # fmt: skip
    n10 = compose_config(["agent=sac_plain_red_n10"]).agent
    for preset, aid in (("sac_plain_red_n10_sil", "self_imitation"),
                        ("sac_plain_red_n10_count", "count_bonus"),
                        ("sac_plain_guard", "limit_guard")):  # fmt: skip
        agent = compose_config([f"agent={preset}"]).agent
        assert list(agent.aids) == ["coloured_noise", aid], preset
        assert {k for k in n10 if k not in ("name", "aids") and agent[k] != n10[k]} == set()
    guard = compose_config(["agent=sac_plain_guard"]).agent
    g996 = compose_config(["agent=sac_plain_guard_g996"]).agent
    assert {k for k in guard if k != "name" and g996[k] != guard[k]} == {"gamma"}
    assert g996.gamma == 0.996
    crossq = compose_config(["agent=crossq_plain_guard_g996"]).agent
    assert {k for k in g996 if k != "name" and crossq[k] != g996[k]} == {"algo", "gradients"}
    assert (crossq.algo, crossq.gradients) == ("crossq", "autograd")
    missed = compose_config(["agent=crossq_plain_guard_g996_missed"]).agent
    assert {k for k in crossq if k not in ("name", "aids") and missed[k] != crossq[k]} == set()
    assert list(missed.aids) == [*crossq.aids, "missed_targets"]
    assert (missed.aids.missed_targets.share, missed.aids.missed_targets.memory) == (0.25, 32)
    utd1 = compose_config(["agent=crossq_plain_guard_g998_utd1"]).agent
    assert {k for k in crossq if k != "name" and utd1[k] != crossq[k]} == {
        "gamma",
        "gradient_steps",
    }
    assert (utd1.gamma, utd1.gradient_steps, utd1.n_envs) == (0.998, 8, 8)
    plain = compose_config(["agent=sac_plain"]).agent
    for preset, changed in (
        ("sac_plain_red", set()),
        ("sac_plain_red_n10", {"n_steps"}),
        ("crossq_plain_red_n10", {"n_steps", "algo", "gradients"}),
        ("sac_plain_red_n10_g998", {"n_steps", "gamma"}),
    ):
        red = compose_config([f"agent={preset}"]).agent
        assert list(red.aids) == ["coloured_noise"] and red.aids.coloured_noise.beta == 2.0
        differs = {k for k in plain if k not in ("name", "aids") and red[k] != plain[k]}
        assert differs == changed, preset
    assert compose_config(["agent=sac_plain_red_n10"]).agent.n_steps == 10
    # The aided presets are the ones that may use privileged knowledge.
    assert compose_config(["agent=sac_quick"]).agent.privileged is True


PRIVILEGED_AIDS = [a for a in aids.AIDS if a.privileged]


@pytest.mark.parametrize("preset", NON_PRIVILEGED)
@pytest.mark.parametrize("aid", PRIVILEGED_AIDS, ids=lambda a: a.name)
def test_a_privileged_aid_in_a_non_privileged_preset_is_one_sentence_and_no_run(
    preset: str, aid: aids.AidDeclaration, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    added = f"+agent.aids.{aid.name}={{_target_: {aid.target}}}"
    assert main(["train", f"agent={preset}", added, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert f"agent.aids.{aid.name} is not allowed with agent.privileged=false" in err
    without = (
        "(averaging, curriculum, missed_targets, random_starts, her, coloured_noise, "
        "self_imitation, count_bonus, limit_guard, late_phase)"
    )
    assert f"a non-privileged preset takes only aids without it {without}" in err
    assert not (runs_dir / "mlflow.db").exists() or not stage_runs(runs_dir, "train")


def test_a_privileged_training_callback_is_refused_too(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    added = "+train.callbacks.labels={_target_: armexp.agents.expert.DaggerExpert}"
    assert main(["train", "agent=sac_plain", added, f"tracking.runs_dir={runs_dir}"]) == 2
    assert "train.callbacks.labels is not allowed with agent.privileged=false" in (
        capsys.readouterr().err
    )


def test_an_aid_without_privileged_knowledge_is_allowed_and_an_aided_preset_unchanged() -> None:
    averaging = "+agent.aids.averaging={_target_: armexp.agents.averaging.WeightAveraging}"
    assert "averaging" in compose_config(["agent=sac_plain", averaging]).agent.aids
    assert compose_config(["agent=sac_plain", "agent.privileged=true"]).agent.privileged
    assert len(compose_config(["agent=sac_quick"]).agent.aids) == 4


@pytest.mark.long
def test_training_sac_plain_imports_no_planner_aid_and_reports_it_not_aided(
    runs_dir: Path,
) -> None:
    # A fresh interpreter, so that no other test's imports count: the train stage of the plain
    # preset never loads the modules of the aids that use the planner or the obstacles.
    code = (
        "import sys, json; from armexp.cli import main; "
        f"rc = main(['train', *{_tiny('sac_plain')!r}, 'tracking.runs_dir={runs_dir}']); "
        "print(json.dumps([rc, sorted(m for m in sys.modules if m.startswith('armexp.'))]))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True
    ).stdout
    rc, modules = json.loads(out.strip().splitlines()[-1])
    assert rc == 0
    assert "armexp.agents.sac" in modules  # the import list is the training's
    assert not set(modules) & set(aids.privileged_modules())
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.tags["armexp.agent_preset"] == "sac_plain"
    from armexp.report.agent import agent_info

    cfg = cast(
        dict[str, Any], OmegaConf.to_container(compose_config(_tiny("sac_plain")), resolve=True)
    )
    assert isinstance(cfg, dict)
    info = agent_info(run.info.run_id, run, cfg)
    assert info.aids == [] and not info.aided
    assert info.label == "sac_plain (plain SAC, no learning aids)"


# ----------------------------------------------------------------------- Table II at speed
def test_sac_paper_fast_keeps_every_table_ii_value() -> None:
    cfg = compose_config(["agent=sac_paper_fast"])
    fast, plain_paper = cfg.agent, compose_config(["agent=sac_paper"]).agent
    for key in TABLE_II_AGENT:
        assert fast[key] == paper.TABLE_II[key], key
    assert cfg.env.action_period == paper.TABLE_II["action_period"]
    assert cfg.env.max_steps == paper.TABLE_II["max_steps"]
    assert list(cfg.robot.velocity_bound) == paper.TABLE_II["velocity_bound"]
    differs = {k for k in plain_paper if plain_paper[k] != fast[k]}
    # Only what Table II leaves open, and the budget.
    assert differs == {"name", "n_envs", "gradient_steps", "gradients", "max_env_steps",
                       "max_minutes"}  # fmt: skip
    assert fast.max_env_steps >= 1_000_000


def test_sac_paper_sets_what_table_ii_leaves_open_as_paper_py_says() -> None:
    agent = OmegaConf.to_container(compose_config(["agent=sac_paper"]).agent)
    assert isinstance(agent, dict)
    for key, value in paper.TABLE_II_OPEN.items():
        assert agent[key] == value, key
    for key in TABLE_II_AGENT:
        assert agent[key] == paper.TABLE_II[key], key


def _table_two(preset: str) -> dict[str, str]:
    cfg = cast(
        dict[str, Any], OmegaConf.to_container(compose_config([f"agent={preset}"]), resolve=True)
    )
    assert isinstance(cfg, dict)
    shown = table_two(cfg).shown
    return dict(zip(shown["Parameter"], shown["Value"], strict=True))


def test_table_ii_lists_each_change_of_sac_paper_fast_as_not_aided() -> None:
    rows = _table_two("sac_paper_fast")
    assert rows["Aided"] == "no"
    assert rows["Changed from Table II"] == (
        "not aided (none uses privileged knowledge): parallel environments 1 → 8; gradients "
        "autograd → compiled; gradient steps per environment step 1 → 0.25 (2 every 1 step(s) "
        "of all environments); budget ≤ 1,000,000 environment steps"
    )
    assert _table_two("sac_paper")["Changed from Table II"] == "none: the paper's SAC as printed"


def test_table_ii_names_the_changed_table_ii_values_and_the_aids_of_an_aided_preset() -> None:
    plain_row = _table_two("sac_plain")["Changed from Table II"]
    assert plain_row.startswith("not aided (none uses privileged knowledge): batch size 512 → 256;")
    assert "n-step returns 1 → 5" in plain_row and "gamma" not in plain_row  # gamma kept
    quick = _table_two("sac_quick")["Changed from Table II"]
    assert quick.startswith(
        "aided (demonstrations, behaviour cloning, DAgger expert use privileged knowledge): "
    )
    assert "gamma 0.995 → 0.99" in quick and "1000 planner demonstrations" in quick
    cfg = cast(
        dict[str, Any], OmegaConf.to_container(compose_config(["agent=td3_quick"]), resolve=True)
    )
    assert isinstance(cfg, dict)
    from armexp.report.agent import AgentInfo

    assert "algorithm SAC → TD3" in changes(cfg, AgentInfo("", "td3_quick", algo="td3"))


# -------------------------------------------------------------------- experiments and study
def test_experiment_plain_runs_sac_plain_with_100_held_out_targets_and_checks() -> None:
    cfg = compose_config(["experiment=plain"])
    assert cfg.agent.name == "sac_plain" and cfg.agent.privileged is False
    assert cfg.tasks.n_random == 100
    assert cfg.train.eval_every > 0
    assert cfg.agent.max_env_steps >= 1_000_000


def test_reproduce_runs_the_plain_rows_in_steps_beside_its_aided_agent() -> None:
    from armexp.stages.study import agent_configs

    cfg = compose_config(["experiment=reproduce"])
    others = {preset: (seeds, c.agent) for preset, seeds, c in agent_configs(cfg)}
    assert set(others) == {"sac_plain_red_n10", "sac_paper_fast"}
    study_seeds = set(cfg.pipeline.seeds)
    for seeds, agent in others.values():
        assert seeds <= study_seeds
        assert agent.max_env_steps == 1_000_000 and agent.max_minutes is None
        assert agent.privileged is False
    assert len(others["sac_plain_red_n10"][0]) >= 3 and len(others["sac_paper_fast"][0]) >= 2
    # The study's agent.* settings stay sac_quick's own.
    assert others["sac_paper_fast"][1].gradients == "compiled"
    assert cfg.agent.name == "sac_quick" and cfg.agent.max_env_steps == 400_000


@pytest.mark.long
@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ("{preset: sac_nope}", "pipeline.agents[0].preset=sac_nope is not allowed: choose an "
                               "agent preset ("),
        ("{preset: sac_plain, seeds: [5]}", "pipeline.agents[0].seeds=[5] is not allowed: each "
                                            "must be one of pipeline.seeds=[0, 1]"),
        ("{preset: sac_plain, agent: {batch_size: 0}}", "pipeline.agents[0] (agent=sac_plain): "
                                                       "agent.batch_size=0 is not allowed"),
    ],
)  # fmt: skip
def test_a_bad_study_agent_is_one_sentence_and_no_run(
    entry: str, message: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["pipeline", "pipeline.seeds=[0,1]", f"pipeline.agents=[{entry}]"]
    assert main([*args, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and err.count("\n") == 0
    assert not (runs_dir / "mlflow.db").exists() or not stage_runs(runs_dir, "pipeline")


def test_other_agents_without_a_study_are_one_sentence_and_no_run(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["pipeline", "pipeline.agents=[{preset: sac_plain}]"]
    assert main([*args, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0
    assert "pipeline.agents (presets sac_plain) is not allowed without pipeline.seeds" in err
    assert not (runs_dir / "mlflow.db").exists() or not stage_runs(runs_dir, "pipeline")


@pytest.mark.slow  # a study of one seed with a second agent: tune, two trainings, two evals
def test_a_study_trains_and_evaluates_its_other_agents_and_reports_them_side_by_side(
    tmp_path: Path,
) -> None:
    from tests.test_study import SMALL

    runs = tmp_path / "runs"
    plain_agent = (
        "{preset: sac_plain, agent: {max_env_steps: 300, learning_starts: 100, batch_size: 32, "
        "net_arch: [32, 32], gradients: autograd, n_envs: 2}}"
    )
    args = [*SMALL, "pipeline.seeds=[0]", f"pipeline.agents=[{plain_agent}]"]
    assert main(["pipeline", *args, f"tracking.runs_dir={runs}"]) == 0
    trains = stage_runs(runs, "train")
    assert sorted(r.data.tags["armexp.agent_preset"] for r in trains) == ["sac_plain", "sac_smoke"]
    plain_train = next(r for r in trains if r.data.tags["armexp.agent_preset"] == "sac_plain")
    assert plain_train.data.params["agent.max_env_steps"] == "300"
    evals = {r.data.tags.get("armexp.train_run") for r in stage_runs(runs, "eval")}
    assert plain_train.info.run_id in evals
    # The second agent's pipeline reuses the seed's tune runs.
    pipelines = stage_runs(runs, "pipeline", newest_first=False)
    assert any(k.startswith("armexp.reused.tune") for k in pipelines[-1].data.tags)
    summary = (runs / "report" / "tables" / "table2_agent.md").read_text()
    assert "sac_plain" in summary and "sac_smoke" in summary
