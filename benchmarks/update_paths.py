"""Milliseconds per SAC gradient step along every update path, at the presets' sizes, one core.

Run from the repository root (about ten minutes; ``--presets sac_quick`` for one size)::

    python -m benchmarks.update_paths
    python -m benchmarks.update_paths --presets sac_quick --rounds 9 --calls 40

Each preset (`conf/agent/sac_demo.yaml`, ``sac_quick``, ``sac_paper``) gives its networks, batch,
n-step return, discount, learning rate and learned entropy coefficient. Every path samples its
batch from its own replay buffer holding the same 30 k random transitions, and does one gradient
step per call (entropy, critics, actor, target averaging), without actor terms:

- ``sb3``: SB3's ``SAC.train`` (Adam's per-tensor loop);
- ``autograd``: `ResumableSAC.train` with ``agent.gradients`` so (``analytic``, the
  hand-written gradients measured in `docs/update_paths.md`, was removed);
- ``fn-adam``: ``agent.gradients=compiled`` (`armexp.agents.compiled`), Adam in the graph, with
  graph breaks allowed; ``fn-adam-full`` as the product runs it (``fullgraph``, static shapes);
  ``fn-adam-full-xK``: the preset's K gradient steps of a call in one graph, as training calls it;
- ``fn-cpp``, ``fn-tensor-guards``, ``fn-no-guards`` (``-xK`` as above): the product's graph with
  inductor's C++ wrapper, with Dynamo's guards on tensors only, with none (`VARIANTS`; measured
  in `docs/update_paths.md`, run 5, not used by training);
- ``compile`` and ``compile-max``: the update as one function of the batch and the policy noise
  (`TorchUpdate`) through ``torch.compile`` in its ``default`` and
  ``max-autotune-no-cudagraphs`` modes; ``eager-func`` is that function uncompiled;
- ``sbx``: SBX's jitted SAC (JAX on the CPU); ``sbx-x2`` two steps per jitted call, as the
  presets with ``gradient_steps: 2`` would call it.

The paths run interleaved (``--calls`` calls of each in turn, ``--rounds`` times) so that other
load on the machine falls on all of them; the table gives medians over rounds, the ratio to
``sb3`` in the same round, process CPU time over wall time (above 1: more than one thread
worked), and the ratio to the floor: the update's matrix-product FLOPs (`update_flops`) at one
core's matmul rate measured in this run (`benchmarks.pace`). Two more columns come from
``torch.profiler`` over ``--calls`` further calls of each torch path: ``matmul ms``, the time per
step inside its matrix-product kernels, and ``sb3/matmul``, SB3's time over that: the most the
path could beat SB3 by were everything but its products free (its ceiling). Before timing, every
torch path takes the same three steps from the same initial weights and batches, and the script
prints the largest difference of its losses, gradients and weights from ``autograd``'s.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import statistics
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch._inductor.config
from omegaconf import DictConfig
from stable_baselines3 import SAC
from stable_baselines3.common.logger import configure
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp.agents.compiled import CompiledUpdate
from armexp.agents.sac import ResumableSAC, build_sac, sac_kwargs
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from benchmarks.pace import measure
from benchmarks.update_variants import TorchUpdate, update_flops

PRESETS = ("sac_demo", "sac_quick", "sac_paper")
#: The product's graph (`fn-adam-full`) with other compiler options: inductor's C++ wrapper (the
#: kernels called from C++, not Python), and Dynamo checking only its guards on tensors or none.
VARIANTS: dict[str, Callable[[], dict[str, Any]]] = {
    "fn-cpp": lambda: {"cpp_wrapper": True},
    "fn-tensor-guards": lambda: {"guard_filter_fn": torch.compiler.keep_tensor_guards_unsafe},
    "fn-no-guards": lambda: {"guard_filter_fn": torch.compiler.skip_all_guards_unsafe},
}
FILLED = 30_000  # transitions in every replay buffer
CHECK_STEPS = 3
# One core for XLA as for torch; read when jax is first imported (lazily, by the sbx path).
XLA_ONE_CORE = (
    "--xla_force_host_platform_device_count=1 --xla_cpu_multi_thread_eigen=false "
    "intra_op_parallelism_threads=1"
)


class _SB3Update(ResumableSAC):
    train = SAC.train


class _Stub(gym.Env):
    """The task's spaces; never stepped (the buffers are filled directly)."""

    def __init__(self, observation_space: gym.Space, action_space: gym.Space) -> None:
        self.observation_space, self.action_space = observation_space, action_space


@dataclass
class Path:
    name: str
    step: Callable[[], Any]  # one gradient step (or `per_call` of them)
    per_call: int = 1
    model: Any = None
    first_s: float = math.nan  # the first call: compilation and warm-up
    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)


def _fill(model: Any, n_envs: int) -> None:
    rng = np.random.default_rng(0)
    buffer, dim = model.replay_buffer, model.observation_space.shape[0]
    for _ in range(FILLED // n_envs):
        obs = rng.normal(size=(n_envs, dim)).astype(np.float32)
        next_obs = rng.normal(size=(n_envs, dim)).astype(np.float32)
        actions = rng.uniform(-1, 1, (n_envs, model.action_space.shape[0]))
        buffer.add(obs, next_obs, actions, rng.normal(size=n_envs), rng.random(n_envs) < 0.005,
                   [{}] * n_envs)  # fmt: skip
    model.set_logger(configure(None, []))


def _torch_paths(agent: DictConfig, env: DummyVecEnv, skip: set[str]) -> list[Path]:
    n = int(agent.batch_size)
    paths = []
    k = int(agent.gradient_steps)
    names = ["sb3", "autograd", "eager-func", "compile", "compile-max",
             "fn-adam", "fn-adam-full"] + ([f"fn-adam-full-x{k}"] if k > 1 else [])  # fmt: skip
    names += [f"{v}-x{k}" if k > 1 else v for v in VARIANTS]
    for name in names:
        if name in skip:
            continue
        gradients = "compiled" if "fn-" in name else "autograd"
        agent.gradients = gradients
        if name == "sb3":
            kwargs = sac_kwargs(agent)
            kwargs["policy_kwargs"]["optimizer_kwargs"] = {}  # SB3's default Adam
            model: ResumableSAC = _SB3Update("MlpPolicy", env, seed=0, verbose=0, **kwargs)
        else:
            model = build_sac(agent, env, seed=0)
        _fill(model, env.num_envs)
        if name in ("eager-func", "compile", "compile-max"):
            mode = {"eager-func": "eager", "compile": None}.get(name, "max-autotune-no-cudagraphs")
            update = TorchUpdate(model, mode)
            paths.append(Path(name, functools.partial(update.train, n), model=update))
        elif name.startswith("fn-"):
            # `CompiledUpdate` (agent.gradients=compiled): Adam written in the graph; with
            # fullgraph and static shapes; xK: the preset's K gradient steps in one graph.
            full: dict[str, Any] = {} if "full" in name else {"fullgraph": False, "dynamic": None}
            variant = name.rsplit("-x", 1)[0]
            if variant in VARIANTS:
                full = {"options": VARIANTS[variant]()}
            model._compiled = CompiledUpdate(model, **full)
            steps = k if name.endswith(f"x{k}") and k > 1 else 1
            paths.append(Path(name, functools.partial(model.train, steps, n), per_call=steps,
                              model=model))  # fmt: skip
        else:
            paths.append(Path(name, functools.partial(model.train, 1, n), model=model))

    def sample() -> None:  # what every path spends before its arithmetic
        paths[0].model.replay_buffer.sample(n)
        torch.empty((n, env.action_space.shape[0])).normal_()  # type: ignore[index]
        torch.empty((n, env.action_space.shape[0])).normal_()  # type: ignore[index]

    return [*paths, Path("(sampling)", sample)]


def _graph_breaks(update: TorchUpdate, n: int) -> None:
    """How ``torch.compile`` splits the update (it runs one more update)."""
    import torch._dynamo

    data = update.model.replay_buffer.sample(n)  # type: ignore[union-attr]
    noise = torch.zeros(n, data.actions.shape[1])
    discounts = data.discounts if data.discounts is not None else torch.tensor(0.99)
    explained = torch._dynamo.explain(update.update)(
        data.observations, data.actions, data.next_observations, data.rewards, data.dones,
        discounts, noise, noise,
    )  # fmt: skip
    where: dict[str, list[int]] = {}
    for r in explained.break_reasons:  # the reason, and the update's lines that lead to it
        inner = r.user_stack[-1]
        key = f"{r.reason.splitlines()[0]} (in {inner.name}, {inner.filename.split('/')[-1]})"
        where.setdefault(key, []).append(r.user_stack[0].lineno or 0)
    print(
        f"  torch.compile: {explained.graph_count} graphs, {explained.graph_break_count} "
        "graph breaks:"
    )
    for reason, lines in where.items():
        print(f"    {reason}: update lines {sorted(set(lines))}")


def _sbx_paths(agent: DictConfig, env: DummyVecEnv) -> list[Path]:
    os.environ.setdefault("XLA_FLAGS", XLA_ONE_CORE)
    os.environ.setdefault("JAX_PLATFORMS", "cpu")
    try:
        import sbx
    except ImportError:
        return []
    arch = sac_kwargs(agent)["policy_kwargs"]["net_arch"]
    model = sbx.SAC(
        "MlpPolicy", env, seed=0, verbose=0, batch_size=int(agent.batch_size),
        tau=float(agent.tau), buffer_size=int(agent.buffer_size), gamma=float(agent.gamma),
        learning_rate=float(agent.learning_rate), n_steps=int(agent.n_steps),
        ent_coef=agent.ent_coef, policy_kwargs={"net_arch": arch}, learning_starts=0,
    )  # fmt: skip
    _fill(model, env.num_envs)
    n = int(agent.batch_size)
    paths = [Path("sbx", lambda: model.train(1, n), model=model)]
    if int(agent.gradient_steps) > 1:
        k = int(agent.gradient_steps)
        paths.append(Path(f"sbx-x{k}", lambda: model.train(k, n), per_call=k, model=model))
    return paths


def _snapshot(model: ResumableSAC) -> tuple[list[torch.Tensor], list[torch.Tensor]]:
    params: list[torch.Tensor] = [*model.actor.parameters(), *model.critic.parameters()]
    if model.log_ent_coef is not None:
        params.append(model.log_ent_coef)
    grads = [torch.zeros(()) if p.grad is None else p.grad.detach().clone() for p in params]
    return [p.detach().clone() for p in params], grads


def _check(paths: list[Path], n: int) -> None:
    """The same steps on the same batches and noise: largest differences from ``autograd``."""
    torch_paths = [p for p in paths if isinstance(p.model, ResumableSAC | TorchUpdate)
                   and p.per_call == 1]  # fmt: skip
    losses: dict[str, list[float]] = {p.name: [] for p in torch_paths}
    for step in range(CHECK_STEPS):
        for p in torch_paths:
            np.random.seed(step)
            torch.manual_seed(step)
            start = time.perf_counter()
            if isinstance(p.model, TorchUpdate):
                losses[p.name] += p.model.train(n)
            else:
                p.model.train(1, n)
                logged = p.model.logger.name_to_value
                losses[p.name] += [logged[f"train/{k}"] for k in ("ent_coef_loss", "critic_loss",
                                                                  "actor_loss")]  # fmt: skip
            if step == 0:
                p.first_s = time.perf_counter() - start
    models = {p.name: p.model.model if isinstance(p.model, TorchUpdate) else p.model
              for p in torch_paths}  # fmt: skip
    ref_params, ref_grads = _snapshot(models["autograd"])
    print(f"  after {CHECK_STEPS} identical steps, largest |difference| from autograd:")
    for p in torch_paths:
        if p.name == "autograd":
            continue
        params, grads = _snapshot(models[p.name])
        dl = max(abs(a - b) for a, b in zip(losses[p.name], losses["autograd"], strict=True))
        dp = max(float((a - b).abs().max()) for a, b in zip(params, ref_params, strict=True))
        # SB3's actor loss leaves its gradient in the critics' (which its next step zeroes).
        actor_only = slice(0, len(list(models[p.name].actor.parameters())))
        pairs = list(zip(grads, ref_grads, strict=True))
        dg = max(float((a - b).abs().max()) for a, b in (pairs[actor_only] if p.name == "sb3"
                                                        else pairs))  # fmt: skip
        if p.name.startswith("fn-"):  # CompiledUpdate keeps no gradients (tests compare them)
            dg = math.nan
        ok = all(torch.allclose(a, b, rtol=1e-4, atol=1e-5) for a, b in zip(params, ref_params,
                                                                          strict=True))  # fmt: skip
        print(f"    {p.name:<20} losses {dl:.1e}  gradients {dg:.1e}  weights {dp:.1e}  "
              f"weights allclose: {ok}")  # fmt: skip


def _time(paths: list[Path], rounds: int, calls: int) -> None:
    for p in paths:  # warm-up (and compilation, for paths not timed by `_check`)
        start = time.perf_counter()
        p.step()
        if math.isnan(p.first_s):
            p.first_s = time.perf_counter() - start
        for _ in range(5):
            p.step()
    for _ in range(rounds):
        for p in paths:
            wall, cpu = time.perf_counter(), time.process_time()
            for _ in range(calls):
                p.step()
            steps = calls * p.per_call
            p.wall.append((time.perf_counter() - wall) / steps * 1e3)
            p.cpu.append((time.process_time() - cpu) / steps * 1e3)


MATMULS = ("aten::mm", "aten::addmm", "aten::bmm", "aten::baddbmm")


def _matmul_ms(path: Path, calls: int) -> float:
    """Milliseconds per gradient step that ``path`` spends inside matrix-product kernels
    (``torch.profiler``'s self CPU time of the aten products over ``calls`` calls)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(calls):
            path.step()
    us = sum(e.self_cpu_time_total for e in prof.key_averages() if e.key in MATMULS)
    return us / 1e3 / (calls * path.per_call)


def run_preset(
    preset: str, rounds: int, calls: int, gflops: float, skip: set[str], explain: bool
) -> None:
    cfg = compose_config(["controller.gains=paper", f"agent={preset}"])
    agent = cfg.agent
    probe = make_vec_env(settings_from_config(cfg), 1, "dummy", 0)
    spaces = (probe.observation_space, probe.action_space)
    env = DummyVecEnv([lambda: _Stub(*spaces)] * int(agent.n_envs))
    pi = list(agent.net_arch)
    qf = list(agent.critic_arch) if agent.critic_arch is not None else pi
    obs_dim, act_dim = spaces[0].shape[0], spaces[1].shape[0]  # type: ignore[index]
    n = int(agent.batch_size)
    print(f"\n{preset}: actor {pi}, critics 2x{qf}, batch {n}, n_steps {agent.n_steps}, "
          f"ent_coef {agent.ent_coef}, obs {obs_dim}, actions {act_dim}")  # fmt: skip
    paths = _torch_paths(agent, env, skip) + _sbx_paths(agent, env)
    paths = [p for p in paths if p.name not in skip]
    if not any(p.name == "sbx" for p in paths) and "sbx" not in skip:
        print("  sbx: not installed (pip install -c constraints.txt sbx-rl jax)")
    _check(paths, n)
    _time(paths, rounds, calls)
    flops = update_flops(obs_dim, act_dim, pi, qf, n)
    floor = flops / (gflops * 1e9) * 1e3
    sb3 = next(p for p in paths if p.name == "sb3")
    sb3_ms = statistics.median(sb3.wall)
    print(f"  floor: {flops / 1e6:.1f} MFLOP per step at {gflops:.1f} GFLOP/s = {floor:.2f} ms")
    print(f"  {'path':<20}{'ms/step':>9}{'sb3/path':>10}{'path/floor':>12}{'cpu/wall':>10}"
          f"{'first call s':>14}{'matmul ms':>11}{'sb3/matmul':>12}")  # fmt: skip
    for p in paths:
        ms = statistics.median(p.wall)
        speedup = statistics.median(a / b for a, b in zip(sb3.wall, p.wall, strict=True))
        usage = statistics.median(c / w for c, w in zip(p.cpu, p.wall, strict=True))
        # The path's own matrix products, and the most it could beat SB3 by if nothing else
        # (kernels, guards, sampling, Python) took any time: its ceiling at these products.
        mm = _matmul_ms(p, calls) if isinstance(p.model, ResumableSAC | TorchUpdate) else math.nan
        print(f"  {p.name:<20}{ms:>9.2f}{speedup:>10.2f}{ms / floor:>12.2f}{usage:>10.2f}"
              f"{p.first_s:>14.2f}{mm:>11.2f}{sb3_ms / mm:>12.2f}")  # fmt: skip
    if explain:
        torch_update = [p.model for p in paths if isinstance(p.model, TorchUpdate)]
        if torch_update:
            _graph_breaks(torch_update[0], n)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS)
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--calls", type=int, default=30, help="calls of each path per round")
    parser.add_argument("--skip", nargs="*", default=[], help="paths to leave out")
    args = parser.parse_args()
    torch.set_num_threads(1)
    torch.set_num_interop_threads(1)
    torch._inductor.config.compile_threads = 1  # compilation on the one core too
    pace = measure()
    print(pace.line())
    print(f"torch {torch.__version__}, one thread; XLA_FLAGS={XLA_ONE_CORE}")
    with tempfile.TemporaryDirectory() as cache:
        # A cold compiler cache, so that the first calls show what a fresh install compiles.
        os.environ["TORCHINDUCTOR_CACHE_DIR"] = cache
        for k, preset in enumerate(args.presets):
            run_preset(preset, args.rounds, args.calls, pace.matmul_gflops, set(args.skip), k == 0)


if __name__ == "__main__":
    main()
