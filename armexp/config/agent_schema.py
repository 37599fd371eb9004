"""The ``agent`` group's schema: the options every algorithm shares (Table II's for SAC), and one
section per algorithm for the options only it has (``agent.td3``, ``agent.tqc``,
``agent.crossq``, ``agent.ppo``), whose defaults are their library's.

`armexp.agents.factory` turns an ``agent`` config into the model of ``agent.algo``; which of the
shared options each algorithm reads, maps or leaves out is said there (`armexp.agents.factory`'s
``ALGORITHM``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from armexp.config.checks import (
    Check,
    at_least,
    between,
    checked,
    each,
    matches,
    nonnegative,
    one_of,
    or_null,
    positive,
)

_pos = positive()

#: The algorithms ``agent.algo`` chooses among (SB3's SAC, TD3 and PPO, sb3-contrib's TQC and
#: CrossQ), with the names tables and captions give them.
TITLES = {"sac": "SAC", "td3": "TD3", "tqc": "TQC", "crossq": "CrossQ", "ppo": "PPO"}
ALGORITHMS = tuple(TITLES)


def agent_label(preset: str | None, algo: str | None) -> str | None:
    """An agent's name in run names and reports: its preset, with ``agent.algo`` after it where
    the preset's name does not start with it (``sac_smoke-td3``; ``td3_quick``, and runs stored
    before ``agent.algo`` was recorded, stay as they are)."""
    if not preset or not algo or preset.partition("_")[0] == algo:
        return preset
    return f"{preset}-{algo}"


@dataclass
class TD3Options:
    """TD3's own options (Fujimoto et al., 2018); defaults as SB3's, with the exploration noise
    of rl-baselines3-zoo (SB3 has none by default)."""

    #: Actor and target updates once every ``policy_delay`` critic updates.
    policy_delay: int = checked(2, at_least(1))
    #: Target policy smoothing: the std and clip of the noise on the target action.
    target_policy_noise: float = checked(0.2, nonnegative())
    target_noise_clip: float = checked(0.5, nonnegative())
    #: Std of the Gaussian exploration noise on the (normalised) action; 0: none.
    action_noise: float = checked(0.1, nonnegative())


@dataclass
class TQCOptions:
    """TQC's own options (Kuznetsov et al., 2020); defaults as sb3-contrib's."""

    n_quantiles: int = checked(25, at_least(1))
    n_critics: int = checked(2, at_least(1))
    #: Quantiles of each critic dropped from the target (the overestimation control).
    top_quantiles_to_drop_per_net: int = checked(2, at_least(0))


@dataclass
class CrossQOptions:
    """CrossQ's own options (Bhatt et al., 2024): no target networks, batch renormalisation in
    actor and critics; defaults as sb3-contrib's."""

    policy_delay: int = checked(3, at_least(1))
    batch_norm_momentum: float = checked(0.01, between(0.0, 1.0, lo_open=True))
    #: Steps over which batch renormalisation's corrections are phased in.
    renorm_warmup_steps: int = checked(100_000, at_least(0))


@dataclass
class PPOOptions:
    """PPO's own options (Schulman et al., 2017); defaults as SB3's."""

    #: Steps per environment in each rollout (SB3's ``n_steps``; the rollout is ``n_steps`` ×
    #: ``agent.n_envs`` steps, updated on in minibatches of ``agent.batch_size``).
    n_steps: int = checked(2048, at_least(2))
    n_epochs: int = checked(10, at_least(1))
    gae_lambda: float = checked(0.95, between(0.0, 1.0))
    clip_range: float = checked(0.2, _pos)
    #: PPO's entropy bonus weight (``agent.ent_coef`` is SAC's temperature, which PPO has not).
    ent_coef: float = checked(0.0, nonnegative())
    vf_coef: float = checked(0.5, nonnegative())
    max_grad_norm: float = checked(0.5, _pos)


@dataclass
class AgentConfig:
    """The agent: ``algo`` and its hyper-parameters (Table II for ``sac_paper``)."""

    name: str = MISSING
    algo: str = checked("sac", one_of(*ALGORITHMS))
    batch_size: int = checked(512, at_least(1))
    tau: float = checked(0.001, between(0.0, 1.0, lo_open=True))
    buffer_size: int = checked(1_000_000, at_least(1))
    learning_starts: int = checked(1000, at_least(0))
    gamma: float = checked(0.995, between(0.0, 1.0))
    learning_rate: float = checked(0.001, _pos)
    episodes: int = checked(20000, at_least(1))
    train_freq: int = checked(1, at_least(1))
    gradient_steps: int = checked(1, at_least(1))
    ent_coef: str = checked(
        "auto",
        matches(
            r"auto(_\d+(\.\d*)?([eE][-+]?\d+)?)?|\d+(\.\d*)?([eE][-+]?\d+)?",
            "'auto', 'auto_<initial value>' or a number ≥ 0 (SB3's ent_coef)",
        ),
    )
    #: The entropy target of SAC, TQC and CrossQ (their target_entropy; TD3 and PPO have none);
    #: null: the libraries' "auto", −(action dimensions).
    target_entropy: float | None = None
    #: n-step returns for the critic targets (SB3's n_steps; 1 = plain SAC).
    n_steps: int = checked(1, at_least(1))
    net_arch: list[int] = checked(factory=lambda: [256, 256], check=each(at_least(1)))
    #: The critics' hidden layers, where they differ from the actor's (None: ``net_arch``).
    critic_arch: list[int] | None = checked(None, or_null(each(at_least(1))))
    #: SAC's critics with DroQ's dropout at this rate and layer normalisation
    #: (`armexp.agents.droq`); null: SB3's plain critics. SAC only, with ``gradients=autograd``.
    critic_dropout: float | None = checked(
        None,
        Check(
            lambda v: v is None or (isinstance(v, int | float) and 0 < v < 1),
            "a rate in (0, 1), or null",
        ),
    )
    #: Parallel environments (SB3 VecEnv); ``vec_env`` dummy = in process, subproc = processes.
    n_envs: int = checked(1, at_least(1))
    vec_env: str = checked("dummy", one_of("dummy", "subproc"))
    #: Extra caps on the budget besides ``episodes`` (None: none): environment steps, minutes.
    max_env_steps: int | None = checked(None, or_null(at_least(1)))
    max_minutes: float | None = checked(None, or_null(_pos))
    device: str = checked(
        "cpu", matches(r"cpu|auto|mps|cuda(:\d+)?", "cpu, auto, mps, cuda or cuda:<index>")
    )
    #: How the update runs: ``autograd`` (the library's update through torch's autograd, eager)
    #: or ``compiled`` (SAC only: the same losses as one torch.compile graph,
    #: `armexp.agents.compiled`). ``analytic`` (gradients written out by hand) was removed:
    #: ``compiled`` is faster.
    gradients: str = checked(
        "autograd",
        Check(
            lambda v: v in ("autograd", "compiled"),
            "autograd or compiled (the hand-written analytic gradients were removed; use compiled)",
        ),
    )
    #: Learning aids, by name, in the order they apply: each a config with a ``_target_``
    #: (`armexp.agents.addons`). None for the paper's plain SAC.
    aids: dict[str, Any] = field(default_factory=dict)
    #: Whether the preset may use privileged knowledge (the planner, the obstacles beyond what
    #: the agent observes): false marks a non-privileged preset, whose config check refuses any
    #: aid or training callback declared privileged (`armexp.aids`, docs/design.md §7).
    privileged: bool = True
    #: The options of one algorithm each, read only when ``algo`` is that algorithm.
    td3: TD3Options = field(default_factory=TD3Options)
    tqc: TQCOptions = field(default_factory=TQCOptions)
    crossq: CrossQOptions = field(default_factory=CrossQOptions)
    ppo: PPOOptions = field(default_factory=PPOOptions)
