"""The check of every job of a sweep before any starts: it says what it is doing, and composes
with Hydra once per distinct choice of config groups, applying each job's plain values to that
composition as Hydra would."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from omegaconf import OmegaConf

from armexp.cli import main
from armexp.config import compose_config
from armexp.tracking import sweeps


class Checked(Exception):
    """Raised where the sweep would open its MLflow run: the check is over."""


def count_compositions(monkeypatch: pytest.MonkeyPatch) -> list[list[str]]:
    import armexp.config as config

    calls: list[list[str]] = []
    compose = config.compose

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(list(kwargs.get("overrides") or []))
        return compose(*args, **kwargs)

    monkeypatch.setattr(config, "compose", counted)
    return calls


def stop_before_the_sweep(monkeypatch: pytest.MonkeyPatch) -> None:
    def stop(*args: Any, **kwargs: Any) -> Any:
        raise Checked

    monkeypatch.setattr(sweeps, "open_sweep", stop)


@pytest.mark.long
def test_a_200_job_sweep_is_composed_once_per_choice_of_groups(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = count_compositions(monkeypatch)
    stop_before_the_sweep(monkeypatch)
    args = ["tune", "-m", "tuner.seed=range(0,100)", "controller=subsystem_adaptive,pid",
            "experiment=smoke", f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    with pytest.raises(Checked):
        main(args)
    out = capsys.readouterr().out
    assert "armexp tune: checking the config of each of the 200 jobs before any starts" in out
    # Two choices of groups (the controller), each composed once for its jobs and once more to
    # confirm the first job's config equals Hydra's own; the launcher's settings once.
    assert len(calls) <= 2 * 2 + 1


@pytest.mark.long
def test_jobs_composed_from_a_shared_composition_equal_hydras(tmp_path: Path) -> None:
    from armexp.config.jobs import JobComposer

    overrides = ["controller=pid,subsystem_adaptive", "robot=three_link,two_link_paper",
                 "seed=1,2", "tuner.pa=0.1", "controller.dt=0.002",
                 "tasks.targets=[{name: a, x: 1.2, y: 0.5}]", f"tracking.runs_dir={tmp_path}",
                 "agent=sac_quick", "agent.net_arch=[16,16]"]  # fmt: skip
    composer = JobComposer(stage="train")
    jobs = sweeps.sweep_combinations(overrides)
    assert len(jobs) == 8
    for job in jobs:
        fast = OmegaConf.to_container(composer.compose(job))
        assert fast == OmegaConf.to_container(compose_config(job, stage="train")), job
    # Four choices of groups: each composed for its jobs, and its first job in full.
    assert composer.compositions == 2 * 4


@pytest.mark.long
def test_a_bad_value_in_a_shared_composition_is_the_same_sentence(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from armexp.config import ConfigError
    from armexp.config.jobs import JobComposer

    composer = JobComposer()
    for job in (["seed=1", "robot.lengths=[1.0]"], ["seed=2", "robot.nothing=1"],
                ["seed=3", "robot.lengths=abc"]):  # fmt: skip
        with pytest.raises(ConfigError) as fast:
            composer.compose(job)
        with pytest.raises(ConfigError) as full:
            compose_config(job)
        assert str(fast.value) == str(full.value)
