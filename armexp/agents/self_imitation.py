"""Self-imitation of the agent's own reaching episodes (the ``self_imitation`` aid).

Without a planner, the detours to targets below the base are found only by exploration, now and
then (docs/plain_agent.md). Even once the critic has seen such an episode, SAC's actor follows
the critic's gradient in action space from where its mean is: at the fork where the greedy move
folds the elbow into its limit and the detour swings it the other way, the critic's value of
the two directions has two peaks, and a gradient step from the fold's side does not cross the
valley between them. Self-imitation learning (Oh, Guo, Singh & Lee, ICML 2018) imitates the
agent's own past actions where they did better than it expects now. Here, as a term of SAC's
actor update with the cloning aid's scale (`armexp.agents.terms.weighted_cloning`) and CRR's
binary filter (Wang et al., NeurIPS 2020):

    L_self = w · mean|Q(s, a)| · E_S[1[R(s, a) > Q(s, a)] · ‖μ(s) − a‖²]

with S a batch of states s, actions a and discounted returns R(s, a) = Σ_k γ^k r_{t+k} taken
from the training episodes that reached their target (their return is exact: the episode ended),
Q the critics' smaller value and μ the actor's deterministic action. Where the policy already
does as well, Q ≥ R and the state adds nothing; where a lucky episode did better, the actor is
pulled to its action across the valley. The return uses the environment's own rewards and the
agent's γ; the episodes are the agent's own (its coloured-noise samples included): no planner,
no obstacle knowledge (not privileged).

The episodes kept are the last ``capacity`` steps of reaching episodes; the term joins the actor
update once they fill one batch. Like the cloning aid's added steps they are not part of a
checkpoint: a resumed run collects afresh.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.agents.sac import ResumableSAC
from armexp.agents.terms import TermBatch, weighted_cloning


def discounted_returns(rewards: np.ndarray, gamma: float) -> np.ndarray:
    """R_t = Σ_{k≥t} γ^{k−t} r_k of an episode that ended (no bootstrap), for every step t."""
    out = np.empty(len(rewards), dtype=np.float64)
    running = 0.0
    for t in range(len(rewards) - 1, -1, -1):
        running = float(rewards[t]) + gamma * running
        out[t] = running
    return out


class OwnReaches:
    """The steps of the agent's own reaching episodes, with their returns, and the
    self-imitation loss on them: an `~armexp.agents.terms.ActorTerm` of ``model`` once
    `attach`ed."""

    def __init__(self, model: ResumableSAC, weight: float, capacity: int, seed: int) -> None:
        obs_dim = int(np.prod(model.observation_space.shape))  # type: ignore[arg-type]
        act_dim = int(np.prod(model.action_space.shape))  # type: ignore[arg-type]
        device = model.device
        self.model, self.weight, self.capacity = model, float(weight), int(capacity)
        self.obs = torch.zeros((self.capacity, obs_dim), device=device)
        self.actions = torch.zeros((self.capacity, act_dim), device=device)
        self.returns = torch.zeros(self.capacity, device=device)
        self.added = 0
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.last_loss = float("nan")

    def __len__(self) -> int:
        return min(self.added, self.capacity)

    @property
    def attached(self) -> bool:
        return any(term is self for term in self.model.actor_terms)

    def attach(self) -> None:
        """Join the model's actor updates."""
        if not self.attached:
            self.model.actor_terms.append(self)

    def add(self, obs: np.ndarray, actions: np.ndarray, returns: np.ndarray) -> None:
        """Keep ``obs`` (k, d), ``actions`` (k, n) and ``returns`` (k,), in place of the oldest
        steps once ``capacity`` is full."""
        k, cap = len(actions), self.capacity
        if k > cap:  # only the last capacity steps would stay
            obs, actions, returns = obs[-cap:], actions[-cap:], returns[-cap:]
            self.added += k - cap
            k = cap
        device = self.obs.device
        rows = torch.as_tensor((self.added + np.arange(k)) % cap, device=device)
        for store, new in ((self.obs, obs), (self.actions, actions), (self.returns, returns)):
            store[rows] = torch.as_tensor(new, dtype=store.dtype, device=device)
        self.added += k

    def batch(self) -> TermBatch:
        """``model.batch_size`` kept steps, drawn uniformly."""
        index = torch.randint(
            len(self), (self.model.batch_size,), generator=self.generator, device=self.obs.device
        )
        return self.obs[index], self.actions[index], self.returns[index]

    def value(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None,
    ) -> torch.Tensor:  # fmt: skip
        """L_self above; no side effects, so that a compiled update can trace it."""
        assert returns is not None  # `batch` always gives them
        return weighted_cloning(self.weight, mode, actions, q, (returns > q).to(mode.dtype))

    def record(self, loss: float) -> None:
        """Log an update's loss (``train/self_imitation_loss``, the mean over a call's steps)."""
        self.last_loss = float(loss)
        self.model.logger.record_mean("train/self_imitation_loss", self.last_loss)

    def loss(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None,
    ) -> torch.Tensor:  # fmt: skip
        """`value`, recorded."""
        loss = self.value(mode, actions, q, returns)
        self.record(float(loss.detach()))
        return loss


class ReachingEpisodes(BaseCallback):
    """Follows every training environment's episode (the observation each action was taken at,
    the action as the replay buffer stores it, the reward) and hands each episode that reached
    its target, with its discounted returns, to ``kept``; attaches ``kept`` to the actor update
    once it holds a batch."""

    def __init__(self, kept: OwnReaches, gamma: float) -> None:
        super().__init__()
        self.kept, self.gamma = kept, float(gamma)
        self.episodes: list[tuple[list[np.ndarray], list[np.ndarray], list[float]]] = []
        self.reached = 0

    def _on_training_start(self) -> None:
        self.episodes = [([], [], []) for _ in range(self.training_env.num_envs)]

    def _on_step(self) -> bool:
        obs = np.asarray(self.model._last_obs)  # the observations the actions were taken at
        actions = np.asarray(self.locals["buffer_actions"])
        rewards, dones, infos = self.locals["rewards"], self.locals["dones"], self.locals["infos"]
        for i, episode in enumerate(self.episodes):
            episode[0].append(obs[i].copy())
            episode[1].append(actions[i].copy())
            episode[2].append(float(rewards[i]))
            if not dones[i]:
                continue
            if infos[i].get("is_success"):
                returns = discounted_returns(np.asarray(episode[2]), self.gamma)
                self.kept.add(np.stack(episode[0]), np.stack(episode[1]), returns)
                self.reached += 1
                if len(self.kept) >= self.kept.model.batch_size:
                    self.kept.attach()
            self.episodes[i] = ([], [], [])
        return True


class SelfImitation(TrainingAddOn):
    """Self-imitation (the module doc) with weight ``weight`` on the last ``capacity`` steps of
    the agent's own reaching episodes. Not privileged. SAC only: the term joins SAC's actor
    update (`armexp.agents.sac.ResumableSAC`)."""

    declaration = aids.SELF_IMITATION

    def __init__(self, weight: float = 1.0, capacity: int = 100_000) -> None:
        if not float(weight) > 0 or int(capacity) < 1:
            raise ValueError(f"weight={weight} must be > 0 and capacity={capacity} at least 1")
        self.weight, self.capacity = float(weight), int(capacity)
        self.callback: ReachingEpisodes | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        model = ctx.model
        assert isinstance(model, ResumableSAC)  # its declaration says so
        kept = OwnReaches(model, self.weight, self.capacity, ctx.seed)
        self.callback = ReachingEpisodes(kept, model.gamma)
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        if self.callback is None:
            return {}
        return {
            "final/self_imitation_episodes": float(self.callback.reached),
            "final/self_imitation_steps": float(self.callback.kept.added),
        }
