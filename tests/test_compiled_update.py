"""SAC's compiled update (``agent.gradients=compiled``, armexp.agents.compiled) against the
reference autograd update, and saved, loaded and continued.

Every model here is tiny (32×32 networks, batch 64) so that the few graphs compile quickly; each
configuration compiles once per module, on first use (fixture ``runs``). Tolerances: losses to
1e-5 relative, weights, gradients and Adam's moments `allclose` with rtol 1e-4 and atol 1e-6
(float32 rounding of the same arithmetic in another order; measured differences about 1e-7).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import torch
from omegaconf import DictConfig
from stable_baselines3.common.vec_env import VecEnv

from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.compiled import CompiledUpdate, steps_per_graph
from armexp.agents.demonstrations import Demonstration, demonstrations
from armexp.agents.sac import ResumableSAC, _with_gradients, build_sac, load_sac
from armexp.agents.self_imitation import OwnReaches
from armexp.agents.vec import make_vec_env
from armexp.config import ConfigError, compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv

TINY = ["controller.gains=paper", "agent=sac_smoke", "agent.learning_starts=300",
        "agent.net_arch=[32,32]", "agent.batch_size=64"]  # fmt: skip
#: learned entropy, n-step returns, the cloning or the self-imitation term, four steps per call
#: (the graph of two, run twice); fixed entropy, 1-step.
#: ``eager``: the same function run without compiling it (seconds, in the default set).
CASES = {
    "learned-nstep-cloning": (["agent.ent_coef=auto", "agent.n_steps=3"], "cloning", 4, None),
    "learned-nstep-cloning-eager": (
        ["agent.ent_coef=auto", "agent.n_steps=3"],
        "cloning",
        4,
        "eager",
    ),
    "learned-nstep-self-imitation-eager": (
        ["agent.ent_coef=auto", "agent.n_steps=3"],
        "self_imitation",
        4,
        "eager",
    ),
    "fixed-onestep": (["agent.ent_coef=0.1", "agent.n_steps=1"], None, 1, None),
}
CALLS = 3
RTOL, ATOL = 1e-4, 1e-6


@dataclass
class Run:
    models: dict[str, ResumableSAC]  # by agent.gradients, both trained alike
    before: list[torch.Tensor]
    logged: dict[str, list[dict[str, float]]]
    terms: dict[str, DemonstrationCloning | OwnReaches]
    overrides: list[str]
    steps: int


def _cfg(gradients: str, overrides: list[str]) -> DictConfig:
    return compose_config([*TINY, *overrides, f"agent.gradients={gradients}"])


def _filled(gradients: str, overrides: list[str]) -> ResumableSAC:
    """The case's model after 300 steps of collection, untrained."""
    cfg = _cfg(gradients, overrides)
    env: VecEnv = make_vec_env(settings_from_config(cfg), 2, "dummy", 0)
    model = build_sac(cfg.agent, env, 0)
    model.learn(total_timesteps=300)  # learning_starts is not reached: collection only
    return model


def _params(model: ResumableSAC) -> list[torch.Tensor]:
    extra = [model.log_ent_coef] if model.log_ent_coef is not None else []
    return [*model.actor.parameters(), *model.critic.parameters(),
            *model.critic_target.parameters(), *extra]  # fmt: skip


def _train(model: ResumableSAC, steps: int, seed: int) -> dict[str, float]:
    torch.manual_seed(seed)
    np.random.seed(seed)  # the replay buffer samples with NumPy's global generator
    model.train(gradient_steps=steps, batch_size=64)
    return {k: float(v) for k, v in model.logger.name_to_value.items()}


@pytest.fixture(scope="module")
def demos() -> list[Demonstration]:
    settings = settings_from_config(compose_config(["controller.gains=paper"]))
    return demonstrations(ReachEnv(settings), 4, seed=1)


def _own_reaches(model: ResumableSAC, demos: list[Demonstration]) -> OwnReaches:
    """A self-imitation term holding the demonstrations' steps with returns around the untrained
    critics' values (about 0), so that some beat them and some do not."""
    term = OwnReaches(model, 2.0, capacity=10_000, seed=7)
    obs = np.concatenate([d.obs for d in demos])
    actions = np.concatenate([d.actions for d in demos])
    term.add(obs, actions, np.random.default_rng(0).normal(0.0, 0.5, len(actions)))
    term.attach()
    return term


class Runs(dict[str, Run]):
    """Each case trained `CALLS` calls along both paths from the same weights and batches, on
    first use: a case compiles its own graphs, so the slow-marked case costs nothing by default."""

    def __init__(self, demos: list[Demonstration]) -> None:
        super().__init__()
        self.demos = demos

    def __missing__(self, case: str) -> Run:
        overrides, term, steps, mode = CASES[case]
        models = {g: _filled(g, overrides) for g in ("autograd", "compiled")}
        before = [p.detach().clone() for p in _params(models["autograd"])]
        start = zip(before, _params(models["compiled"]), strict=True)
        assert all(torch.equal(a, b) for a, b in start)
        terms: dict[str, DemonstrationCloning | OwnReaches] = {}
        if term == "cloning":
            terms = {g: DemonstrationCloning(m, self.demos, 3.0, seed=7) for g, m in models.items()}
        if term == "self_imitation":
            terms = {g: _own_reaches(m, self.demos) for g, m in models.items()}
        logged: dict[str, list[dict[str, float]]] = {g: [] for g in models}
        for call in range(CALLS):
            for gradients, model in models.items():
                if gradients == "compiled" and model._compiled is None:
                    model._compiled = CompiledUpdate(model, mode=mode)
                    model._compiled.keep_grads = True  # for the comparison of gradients
                logged[gradients].append(_train(model, steps, seed=call))
        self[case] = Run(models, before, logged, terms, overrides, steps)
        return self[case]


@pytest.fixture(scope="module")
def runs(demos: list[Demonstration]) -> Runs:
    return Runs(demos)


# A compiled case compiles for about a minute on a cold cache: those run with the slow set.
@pytest.mark.long
@pytest.mark.parametrize(
    "case",
    [
        "learned-nstep-cloning-eager",
        "learned-nstep-self-imitation-eager",
        *(
            pytest.param(c, marks=pytest.mark.slow)
            for c in ["learned-nstep-cloning", "fixed-onestep"]
        ),
    ],
)
def test_the_compiled_update_is_autograds_update(runs: Runs, case: str) -> None:
    run = runs[case]
    ours, ref = run.models["compiled"], run.models["autograd"]
    for got, want, was in zip(_params(ours), _params(ref), run.before, strict=True):
        assert not torch.equal(want, was)  # every parameter moved
        assert torch.allclose(got, want, rtol=RTOL, atol=ATOL), float((got - want).abs().max())
    trained: list[torch.Tensor] = [*ref.actor.parameters(), *ref.critic.parameters()]
    mine: list[torch.Tensor] = [*ours.actor.parameters(), *ours.critic.parameters()]
    if ref.log_ent_coef is not None:
        assert ours.log_ent_coef is not None
        trained, mine = [*trained, ref.log_ent_coef], [*mine, ours.log_ent_coef]
    for got, want in zip(mine, trained, strict=True):  # the last step's gradients
        assert got.grad is not None and want.grad is not None
        assert torch.allclose(got.grad, want.grad, rtol=1e-4, atol=1e-5)
    for got_log, want_log in zip(run.logged["compiled"], run.logged["autograd"], strict=True):
        assert got_log.keys() == want_log.keys()
        for key in want_log:
            assert got_log[key] == pytest.approx(want_log[key], rel=1e-5, abs=1e-7), key
    optimizers = ["actor.optimizer", "critic.optimizer"]
    optimizers += ["ent_coef_optimizer"] if ref.ent_coef_optimizer is not None else []
    for name in optimizers:  # Adam's own state, as the eager optimiser leaves it
        got_state = _optimizer(ours, name).state_dict()["state"]
        want_state = _optimizer(ref, name).state_dict()["state"]
        assert got_state.keys() == want_state.keys()
        for index, want_entry in want_state.items():
            assert float(got_state[index]["step"]) == float(want_entry["step"])
            assert float(want_entry["step"]) == CALLS * run.steps
            for key in ("exp_avg", "exp_avg_sq"):
                assert torch.allclose(got_state[index][key], want_entry[key], rtol=1e-4, atol=1e-7)
    if run.terms:
        got_loss, want_loss = run.terms["compiled"].last_loss, run.terms["autograd"].last_loss
        assert got_loss > 0 and got_loss == pytest.approx(want_loss, rel=1e-5)


def _optimizer(model: ResumableSAC, name: str) -> torch.optim.Optimizer:
    owner, _, attr = name.rpartition(".")
    return getattr(getattr(model, owner), attr) if owner else getattr(model, attr)


# The loaded model traces and compiles its own graphs again (a minute or two on a loaded core).
@pytest.mark.slow
def test_a_compiled_model_saved_loaded_and_continued_is_the_model_continued_in_process(
    runs: Runs, demos: list[Demonstration], tmp_path: Path
) -> None:
    run = runs["learned-nstep-cloning"]
    model = run.models["compiled"]
    model.save(tmp_path / "m.zip")
    agent = _cfg("compiled", run.overrides).agent
    loaded = load_sac(str(tmp_path / "m.zip"), model.get_env(), agent)
    assert loaded.gradients == "compiled" and loaded._compiled is None
    assert loaded.actor_terms == []  # terms are the aids', set up again on resume
    loaded.replay_buffer = model.replay_buffer  # as a resumed run refills its own
    loaded.set_logger(model.logger)
    term = DemonstrationCloning(loaded, demos, 3.0, seed=0)
    term.generator.set_state(run.terms["compiled"].generator.get_state())
    for call in range(2):
        for m in (model, loaded):
            _train(m, run.steps, seed=100 + call)
    for got, want in zip(_params(loaded), _params(model), strict=True):
        assert torch.equal(got, want)
    for name in ("actor.optimizer", "critic.optimizer", "ent_coef_optimizer"):
        got_state = _optimizer(loaded, name).state_dict()["state"]
        for index, want in _optimizer(model, name).state_dict()["state"].items():
            assert all(torch.equal(got_state[index][k], want[k]) for k in want)


@pytest.mark.long
def test_one_process_compiles_the_update_of_model_after_model_without_a_recompile_limit() -> None:
    """An HPO trains trial after trial in one process: each model's update compiles against a
    limit of its own (one here), not against a count shared by every model the process made."""
    with torch._dynamo.config.patch(recompile_limit=1):
        for seed in range(3):
            model = _filled("compiled", ["agent.ent_coef=auto", "agent.n_steps=1"])
            model._compiled = CompiledUpdate(model, backend="eager")  # Dynamo without inductor
            before = [p.detach().clone() for p in model.actor.parameters()]
            _train(model, 2, seed)
            after = list(model.actor.parameters())
            assert not all(torch.equal(a, b) for a, b in zip(before, after, strict=True))


def test_a_call_runs_the_graph_of_at_most_two_steps_as_often_as_it_needs() -> None:
    assert [steps_per_graph(n) for n in (1, 2, 3, 4, 7, 8)] == [1, 2, 1, 2, 1, 2]


def test_the_compiled_update_refuses_what_it_does_not_cover() -> None:
    cfg = _cfg("compiled", [])
    env = make_vec_env(settings_from_config(cfg), 1, "dummy", 0)
    model = ResumableSAC("MlpPolicy", env, use_sde=True)
    with pytest.raises(ConfigError) as err:
        _with_gradients(model, cfg.agent)
    assert str(err.value) == (
        "agent.gradients=compiled is not allowed for this agent: gSDE, delayed target updates "
        "and batch norm are not covered; use agent.gradients=autograd."
    )
    decay_kwargs = {"optimizer_kwargs": {"weight_decay": 0.1}}
    decay = ResumableSAC("MlpPolicy", env, policy_kwargs=decay_kwargs)
    assert CompiledUpdate.supports(decay) == (
        "it writes Adam's update without weight decay, amsgrad or maximize"
    )
    assert CompiledUpdate.supports(_filled("compiled", [])) is None


def test_a_config_asking_for_the_removed_analytic_gradients_is_told_to_use_compiled(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from armexp.cli import main

    rc = main(["train", "agent.gradients=analytic", f"tracking.runs_dir={tmp_path / 'runs'}"])
    assert rc == 2 and capsys.readouterr().err.strip().splitlines() == [
        "armexp train: agent.gradients='analytic' is not allowed: autograd or compiled (the "
        "hand-written analytic gradients were removed; use compiled)."
    ]
    assert not (tmp_path / "runs").exists()
