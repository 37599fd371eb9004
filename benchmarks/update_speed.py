"""Time per SAC gradient step of the `sac_demo` update, against SB3's own update.

Run from the repository root (about a minute)::

    python benchmarks/update_speed.py
    python benchmarks/update_speed.py --rounds 7 --calls 150

One process, one torch thread. Each variant is `sac_demo`'s model (``experiment=demo``) on a
replay buffer of 30 k random steps, with the behaviour-cloning term on 200 k labelled states
(about what five minutes of training hold). The variants run in turn, ``--rounds`` times
``--calls`` updates of two gradient steps each, and the script prints each variant's median
milliseconds per gradient step and its ratio to SB3's update measured in the same rounds:

- ``sb3``: SB3's ``SAC.train`` with Adam's per-tensor loop, the cloning gradient added by an
  optimiser hook before the actor's step;
- ``autograd``: `ResumableSAC.train` (``agent.gradients=autograd``), which gives the same
  parameters as ``sb3`` (``tests/test_sac.py``);
- ``compiled``: `ResumableSAC.train` with ``agent.gradients=compiled``, the update as one
  ``torch.compile`` graph per call (the same update to rounding,
  ``tests/test_compiled_update.py``); its first call, which compiles, is not timed.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC

from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.demonstrations import Demonstration
from armexp.agents.sac import ResumableSAC, sac_kwargs
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config


class _SB3Update(ResumableSAC):
    train = SAC.train


def _model(variant: str) -> ResumableSAC:
    gradients = "compiled" if variant == "compiled" else "autograd"
    cfg = compose_config(
        ["controller.gains=paper", "experiment=demo", f"agent.gradients={gradients}"]
    )
    env = make_vec_env(settings_from_config(cfg), int(cfg.agent.n_envs), "dummy", 0)
    kwargs: dict[str, Any] = sac_kwargs(cfg.agent)
    if variant == "sb3":
        kwargs["policy_kwargs"]["optimizer_kwargs"] = {}
    cls = _SB3Update if variant == "sb3" else ResumableSAC
    model = cls("MlpPolicy", env, seed=0, verbose=0, **kwargs)
    model.gradients = gradients
    model.learn(total_timesteps=int(cfg.agent.learning_starts))  # sets up the logger
    rng = np.random.default_rng(0)
    dim, n_envs = env.observation_space.shape[0], env.num_envs  # type: ignore[index]
    for _ in range(30_000 // n_envs):
        obs = rng.normal(size=(n_envs, dim)).astype(np.float32)
        model.replay_buffer.add(  # type: ignore[union-attr]
            obs, obs, rng.uniform(-1, 1, (n_envs, 2)), rng.normal(size=n_envs),
            rng.random(n_envs) < 0.005, [{}] * n_envs,
        )  # fmt: skip
    labelled = 200_000
    demo = Demonstration(
        obs=rng.normal(size=(labelled, dim)).astype(np.float32), next_obs=np.empty(0),
        actions=rng.uniform(-1, 1, (labelled, 2)).astype(np.float32), rewards=np.empty(0),
        terminated=np.empty(0), reason="reached",
    )  # fmt: skip
    term = DemonstrationCloning(model, [demo], 3.0, seed=0)
    if variant == "sb3":
        model.actor_terms.remove(term)

        def add_gradient(*_: object) -> None:
            with torch.enable_grad():
                obs, actions, returns = term.batch()
                with torch.no_grad():
                    q = torch.cat(model.critic(obs, actions), dim=1).min(dim=1).values
                term.loss(model.actor(obs, deterministic=True), actions, q, returns).backward()

        model.actor.optimizer.register_step_pre_hook(add_gradient)
    return model


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--calls", type=int, default=100, help="updates (2 steps each) per round")
    args = parser.parse_args()
    torch.set_num_threads(1)
    variants = ["sb3", "autograd", "compiled"]
    models = {v: _model(v) for v in variants}
    batch = int(compose_config(["experiment=demo"]).agent.batch_size)
    models["compiled"].train(gradient_steps=2, batch_size=batch)  # compiles
    times: dict[str, list[float]] = {v: [] for v in variants}
    for _ in range(args.rounds):
        for v in variants:
            start = time.perf_counter()
            for _ in range(args.calls):
                models[v].train(gradient_steps=2, batch_size=batch)
            times[v].append((time.perf_counter() - start) / (2 * args.calls) * 1e3)
    base = statistics.median(times["sb3"])
    print(f"{'variant':<14}{'ms per gradient step (median)':>32}{'sb3 / variant':>16}")
    for v in variants:
        ratios = [a / b for a, b in zip(times["sb3"], times[v], strict=True)]
        ms = statistics.median(times[v])
        print(f"{v:<14}{ms:>32.2f}{statistics.median(ratios):>16.2f}")
    print(f"(sb3: {base:.2f} ms; {args.rounds} rounds of {args.calls} updates, one torch thread)")


if __name__ == "__main__":
    main()
