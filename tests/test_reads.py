"""What a stage reads (armexp.reads): the view it runs on, the digest its runs are reused by, and
reuse (armexp.tracking.reuse), also of runs made before the declarations."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import pytest
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import ConfigAttributeError, ReadonlyConfigError

from armexp.reads import Reads, UndeclaredRead
from armexp.stages import evaluate, simulate, train, tune
from armexp.tracking import reuse, store
from armexp.tracking.stage_runs import StageResult
from armexp.tracking.tags import INPUTS_TAG
from tests.helpers import SMALL_TRAIN, SMALL_TUNE, stage_runs

#: Every stage whose runs ``pipeline.reuse`` may reuse, by its name.
STAGES: dict[str, ModuleType] = {"simulate": simulate, "tune": tune, "train": train,
                                 "eval": evaluate}  # fmt: skip
#: What a stage may read without hashing it: where and how it records. Anything else it reads
#: changes its result and is hashed; a key moved here is a decision this list has to show.
BOOKKEEPING = ("tracking", "{stage}.run_name", "{stage}.progress")
NOT_RESULTS = {
    # The run a resume continues (the continued run's own config is hashed), the torch threads
    # (how fast), how often the checkpoint is written and the episode metrics flushed.
    "train": ("train.resume", "train.torch_threads", "train.checkpoint_every", "train.log_every"),
}
SIM = ["scenario.duration=0.2"]


def _tagged(runs: Path, stage: str, result: StageResult) -> Any:
    """The stage run of ``result``, FINISHED."""
    (run,) = [r for r in stage_runs(runs, stage) if r.info.run_id == result.run_id]
    assert run.info.status == "FINISHED"
    return run


# ----------------------------------------------------------------------------- the view
def _view(cfg: DictConfig) -> DictConfig:
    hashed = ("robot", "tuner", "env.id")
    reads = Reads("tune", hashed=hashed, unhashed=("tune.progress", "tracking"))
    return reads.view(cfg)


@pytest.mark.parametrize(
    "read",
    [
        lambda v: v.env.reference,
        lambda v: v["env"]["reference"],
        lambda v: v.env.get("reference", "ramp"),
        lambda v: OmegaConf.select(v, "env.reference", default="ramp"),
        lambda v: dict(v.env),
        lambda v: OmegaConf.to_container(v.env, resolve=True),
    ],
    ids=["attribute", "item", "get", "select", "dict", "to_container"],
)
def test_reading_an_undeclared_key_raises_naming_the_stage_and_the_key(
    read: Callable[[DictConfig], Any], compose: Callable[..., DictConfig]
) -> None:
    view = _view(compose())
    with pytest.raises(UndeclaredRead) as caught:
        read(view)
    stage, key = caught.value.stage, caught.value.key
    assert stage == "tune" and key.startswith("env.")  # reference, or the first key read
    assert str(caught.value).startswith(f"the tune stage read the config key {key}, ")


def test_a_view_holds_the_declared_keys_resolved_and_nothing_else(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose("experiment=reproduce", "seed=3")  # tuner.seed: ${seed}
    view = _view(cfg)
    assert view.tuner.seed == 3 and view.tune.progress is None
    assert OmegaConf.to_container(view.robot) == OmegaConf.to_container(cfg.robot, resolve=True)
    with pytest.raises(UndeclaredRead, match="config key agent,"):
        view.agent.name  # noqa: B018
    with pytest.raises(UndeclaredRead, match=r"config key tune\.run_name,"):
        view.tune.run_name  # noqa: B018
    with pytest.raises(ConfigAttributeError):  # no config has it
        view.robot.wheels  # noqa: B018
    with pytest.raises(ReadonlyConfigError):  # a write would not reach the logged config
        view.tuner.seed = 4
    assert "agent" in view and list(view) == list(cfg)  # the shape is the config's


def test_a_key_cannot_be_both_hashed_and_unhashed() -> None:
    with pytest.raises(ValueError):
        Reads("x", hashed=("eval",), unhashed=("eval",))
    with pytest.raises(ValueError):
        Reads("x", hashed=("tracking.uri",), unhashed=("tracking",))
    inside = Reads("x", hashed=("eval",), unhashed=("eval.progress",))
    assert inside.hashes("eval.baselines") and not inside.hashes("eval.progress")


def test_a_stage_that_reads_an_undeclared_key_fails_at_once(
    compose: Callable[..., DictConfig], runs_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A tune that also read ``agent.gamma`` (a key its hash omits) fails on that read, its run
    FAILED with the reason."""
    real = tune.build_objective

    def reads_more(cfg: DictConfig, kind: int | None = None) -> Any:
        float(cfg.agent.gamma)
        return real(cfg, kind)

    monkeypatch.setattr(tune, "build_objective", reads_more)
    with pytest.raises(UndeclaredRead, match="the tune stage read the config key agent,"):
        tune.run(compose(*SMALL_TUNE))
    (run,) = stage_runs(runs_dir, "tune")
    assert run.info.status == "FAILED" and "agent" in run.data.tags["armexp.error"]


@pytest.mark.parametrize("stage", STAGES)
def test_only_bookkeeping_is_read_without_being_hashed(stage: str) -> None:
    reads = STAGES[stage].READS
    assert reads.stage == stage
    allowed = {k.format(stage=stage) for k in BOOKKEEPING} | set(NOT_RESULTS.get(stage, ()))
    assert set(reads.unhashed) <= allowed


# ------------------------------------------------------------------- each stage, under its view
@pytest.mark.parametrize(
    "overrides",
    [[], ["scenario=hold"], ["scenario=sine", "env.reference=hold"], ["controller=pid"],
     ["controller=computed_torque", "robot=three_link"]],
)  # fmt: skip
def test_simulate_reads_only_what_it_declares(
    overrides: list[str], compose: Callable[..., DictConfig], runs_dir: Path
) -> None:
    cfg = compose(*SIM, *overrides)
    run = _tagged(runs_dir, "simulate", simulate.run(cfg))
    assert run.data.tags[INPUTS_TAG] == simulate.READS.digest(cfg)


@pytest.mark.parametrize(
    "overrides",
    [["controller=pid", "env.reference=hold"], ["controller=computed_torque"],
     ["tuner.objective.criterion=iae", "tuner.log_space=false", "tuner.abandon=worst"]],
)  # fmt: skip
def test_tune_reads_only_what_it_declares(
    overrides: list[str], compose: Callable[..., DictConfig], runs_dir: Path
) -> None:
    cfg = compose(*SMALL_TUNE, *overrides)
    run = _tagged(runs_dir, "tune", tune.run(cfg))
    assert run.data.tags[INPUTS_TAG] == tune.READS.digest(cfg)


@pytest.fixture(scope="module")
def chain(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A store with a tune run of each controller of the comparison and a train run."""
    runs = tmp_path_factory.mktemp("reads") / "runs"
    where = f"tracking.runs_dir={runs}"
    from armexp.config import compose_config

    tune.run(compose_config([*SMALL_TUNE, where]))
    tune.run(compose_config([*SMALL_TUNE, "controller=pid", where]))
    train.run(compose_config([*SMALL_TRAIN, where]))
    return runs


@pytest.mark.long
@pytest.mark.parametrize(
    "overrides",
    [["train.gains=config", "controller.gains=paper"], ["agent.n_envs=2", "train.eval_every=300",
                                                        "train.eval_targets=2"]],
)  # fmt: skip
def test_train_reads_only_what_it_declares(overrides: list[str], chain: Path) -> None:
    from armexp.config import compose_config

    cfg = compose_config([*SMALL_TRAIN, *overrides, f"tracking.runs_dir={chain}"])
    run = _tagged(chain, "train", train.run(cfg))
    assert run.data.tags[INPUTS_TAG] == train.READS.digest(cfg)


@pytest.mark.long
@pytest.mark.parametrize(
    "overrides",
    [["eval.baselines=[pid_itae]"],
     ["eval.adaptive_gains=config", "eval.baselines=[]", "eval.ablation=false"],
     ["eval.baseline_gains=config", "eval.baselines=[pid_gaing,computed_torque]"],
     ["eval.baselines=[]", "eval.paper_tasks=false", "eval.random_trajectories=true",
      "eval.large_offset=null"]],
)  # fmt: skip
def test_eval_reads_only_what_it_declares(overrides: list[str], chain: Path) -> None:
    from armexp.config import compose_config

    where = f"tracking.runs_dir={chain}"
    trained = stage_runs(chain, "train", newest_first=False)[0].info.run_id
    common = ["tasks.n_random=1", "eval.animations=false", f"eval.train_run={trained}", where]
    cfg = compose_config([*common, *overrides])
    run = _tagged(chain, "eval", evaluate.run(cfg))
    assert run.data.tags[INPUTS_TAG] == evaluate.READS.digest(cfg)


@pytest.mark.long
def test_a_run_made_under_the_earlier_declaration_is_reused_where_its_config_matches(
    chain: Path,
) -> None:
    """Train hashed ``tuner.seed`` once it chose the default tune run; a run tagged with the
    digest of the declaration before is reused only where its logged tuner.seed is the config's."""
    from armexp.config import compose_config

    where = f"tracking.runs_dir={chain}"
    cfg = compose_config([*SMALL_TRAIN, where])
    made = stage_runs(chain, "train", newest_first=False)[0]
    assert made.data.tags[INPUTS_TAG] == train.READS.digest(cfg)
    client = MlflowClient(store.store_uri(cfg))
    earlier = train.READS.earlier_digests(cfg)[0]  # the newest earlier declaration
    client.set_tag(made.info.run_id, INPUTS_TAG, earlier)  # as the armexp before tagged it
    try:
        assert reuse.reusable(cfg, train.READS) == made.info.run_id
        other_seed = compose_config([*SMALL_TRAIN, "tuner.seed=5", where])
        assert train.READS.earlier_digests(other_seed)[0] == earlier  # the old digest is blind
        assert reuse.reusable(other_seed, train.READS) is None
    finally:
        client.set_tag(made.info.run_id, INPUTS_TAG, train.READS.digest(cfg))


# --------------------------------------------------------------------------------- the digest
def _hash_as_armexp_always_did(cfg: DictConfig, keys: tuple[str, ...]) -> str:
    """The ``armexp.inputs_hash`` of runs made before the declarations, over ``keys``."""
    picked = {}
    for key in keys:
        node = OmegaConf.select(cfg, key)
        value = OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node
        picked[key] = {"v": value}
    text = json.dumps(picked, sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def test_the_digest_is_made_as_before_so_earlier_runs_keep_matching(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose("experiment=reproduce")
    for module in STAGES.values():
        reads = module.READS
        before = reads.earlier[-1]  # the list kept by hand before the declarations
        assert reads.earlier_digests(cfg)[-1] == _hash_as_armexp_always_did(cfg, before)


@pytest.mark.long
def test_the_digest_follows_the_inputs_and_nothing_else(
    compose: Callable[..., DictConfig],
) -> None:
    def same(stage: str, a: list[str], b: list[str]) -> bool:
        reads = STAGES[stage].READS
        return bool(reads.digest(compose(*a)) == reads.digest(compose(*b)))

    # Resolved: tuner.seed: ${seed} hashes as the seed it resolves to.
    assert same("tune", ["experiment=reproduce", "seed=3"], ["experiment=reproduce",
                                                             "seed=5", "tuner.seed=3"])  # fmt: skip
    assert not same("tune", ["experiment=reproduce", "seed=3"], ["experiment=reproduce", "seed=4"])
    # What a stage reads to record is not hashed; what it does not read at all neither.
    assert same("tune", [], ["tune.progress=true", "tune.run_name=x", "tracking.runs_dir=/y"])
    assert same("tune", [], ["env.max_steps=10", "agent=sac_quick", "seed=7"])
    assert same("eval", [], ["eval.progress=true", "tuner.objective.horizon=2"])
    assert same("train", [], ["tasks.n_random=3", "train.checkpoint_every=7", "eval.ablation=0"])
    # What it reads to compute is.
    for stage in ("tune", "simulate"):
        assert not same(stage, [], ["env.reference=hold"])
    assert not same("train", [], ["train.eval_every=100"])  # the held-out callback's
    assert not same("train", [], ["tuner.objective.criterion=gaing"])  # which tune run
    assert not same("train", [], ["tuner.seed=3"])  # which tune run, when none is given
    assert not same("eval", [], ["tuner.seed=3"])
    assert not same("eval", [], ["eval.animations=false"])
    assert not same("eval", [], ["obstacles=none"])


# ------------------------------------------------------------------------------------- reuse
@pytest.mark.long
def test_reuse_takes_a_run_with_the_same_inputs_only(
    compose: Callable[..., DictConfig], runs_dir: Path
) -> None:
    """The issue's case: a tune run made with ``env.reference=ramp`` is not the run a ``hold``
    config would make. A run made before the declarations (its digest over the old hand-kept
    list) is taken only when its logged config matches on every key tune reads."""
    ramp = compose(*SMALL_TUNE)
    made = tune.run(ramp).run_id
    assert reuse.reusable(ramp, tune.READS) == made
    assert reuse.reusable(compose(*SMALL_TUNE, "tune.progress=true"), tune.READS) == made
    assert reuse.reusable(compose(*SMALL_TUNE, "env.reference=hold"), tune.READS) is None
    # The same run as an older armexp tagged it.
    client = MlflowClient(store.store_uri(ramp))
    old = _hash_as_armexp_always_did(ramp, tune.READS.earlier[-1])
    client.set_tag(made, INPUTS_TAG, old)
    assert reuse.reusable(ramp, tune.READS) == made
    hold = compose(*SMALL_TUNE, "env.reference=hold")
    assert _hash_as_armexp_always_did(hold, tune.READS.earlier[-1]) == old  # the old bug
    assert reuse.reusable(hold, tune.READS) is None
    assert reuse.reusable(compose(*SMALL_TUNE, "tuner.pa=0.5"), tune.READS) is None
