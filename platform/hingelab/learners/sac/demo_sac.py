"""SAC from demonstrations: ``DemoSAC``, FastSAC with a Q-filtered behaviour-cloning term it owns.

Why: plain SAC on ToolShape-v0 drives the fingers to one end of the hinge range for every goal
(the variants tried and their runs: ``analysis/low-level-ablation/README.md``). The likely cause: the action is a
relative joint change, so the loop integrates any bias of the actor into a drift to a
joint limit, and one step's action moves the latent by less than the perception's
frame-to-frame jitter, so the critic's action gradient is mostly noise. Demonstrations (any
dataset of the task, e.g. the scripted synergy controller's, ``hingelab eval low --baseline
synergy``, or the privileged heuristic's for ToolPick-v0) anchor the actor as in Nair et al.,
"Overcoming Exploration in RL with Demonstrations" (2018):

    actor_loss = SAC actor loss + weight * mean_demo( [Q(s, a_demo) > Q(s, pi(s))] ||pi(s) - a_demo||^2 )

where pi(s) is the actor's deterministic action (tanh of its mean). With ``q_scaled`` the term
is multiplied by mean |Q(s, pi(s))| of the batch (detached), as TD3+BC (Fujimoto and Gu, 2021)
normalizes its Q term: the BC term keeps its share of the actor loss as the returns grow
(weight 0.4 is TD3+BC's alpha = 2.5). The Q-filter drops the
term wherever the critic already prefers the policy's action, so SAC can improve on the
demonstrator; ``bc_weight=0`` is plain (Fast)SAC. ``pretrain_actor`` fits pi to the
demonstrations (behaviour cloning) before the first online step, so training starts from the
demonstrator instead of from noise.

The demonstrations are not saved with the model (a run re-reads them from its ``--from``
datasets on resume); ``bc_weight`` and ``q_filter`` are.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from hingelab.learners.sac.fast_sac import FastSAC

ACTION_LIMIT = 0.97  # demo actions at the +-1 bound are fitted as this (tanh never reaches 1)
STD_FIT_WEIGHT = 0.01  # the likelihood term of pretrain_actor(fit_std=True), against the squared error


@dataclass
class Demonstrations:
    """Demonstration (observation, action) pairs as float32 tensors."""

    observations: Any  # (N, ...) tensor, or key -> (N, ...) tensors for a Dict observation space
    actions: th.Tensor  # (N, A) in [-ACTION_LIMIT, ACTION_LIMIT]

    @classmethod
    def from_transitions(cls, transitions) -> "Demonstrations":
        obs = transitions.observations
        as_tensor = lambda v: th.as_tensor(np.asarray(v), dtype=th.float32)  # noqa: E731
        observations = {k: as_tensor(v) for k, v in obs.items()} if isinstance(obs, dict) else as_tensor(obs)
        return cls(observations, as_tensor(np.clip(transitions.actions, -ACTION_LIMIT, ACTION_LIMIT)))

    def __len__(self) -> int:
        return len(self.actions)

    def batch(self, batch_size: int) -> tuple[Any, th.Tensor]:
        idx = th.from_numpy(np.random.randint(0, len(self), size=batch_size))
        obs = self.observations
        obs = {k: v.index_select(0, idx) for k, v in obs.items()} if isinstance(obs, dict) else obs.index_select(0, idx)
        return obs, self.actions.index_select(0, idx)


class DemoSAC(FastSAC):
    """FastSAC whose actor loss adds ``bc_weight`` x the (Q-filtered) BC term on ``demonstrations``."""

    def __init__(self, *args: Any, bc_weight: float = 0.0, q_filter: bool = True, q_scaled: bool = False,
                 **kwargs: Any):
        self.bc_weight = float(bc_weight)
        self.q_filter = bool(q_filter)
        self.q_scaled = bool(q_scaled)
        self.demonstrations: Demonstrations | None = None
        super().__init__(*args, **kwargs)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "demonstrations"]

    def set_demonstrations(self, demonstrations: Demonstrations | None) -> None:
        self.demonstrations = demonstrations

    def _deterministic_actions(self, obs: Any) -> th.Tensor:
        mean, _, _ = self.actor.get_action_dist_params(obs)
        return th.tanh(mean)

    def bc_loss(self, batch_size: int) -> th.Tensor:
        """The weighted, Q-filtered BC term for one actor update."""
        obs, demo_actions = self.demonstrations.batch(batch_size)
        policy_actions = self._deterministic_actions(obs)
        squared = ((policy_actions - demo_actions) ** 2).sum(dim=1)
        if self.q_scaled:  # TD3+BC: the term keeps its share of the loss whatever the scale of Q
            with th.no_grad():
                q_scale = th.min(th.cat(self.critic(obs, policy_actions), dim=1), dim=1).values.abs().mean()
            squared = squared * q_scale
        if self.q_filter:
            with th.no_grad():
                q_demo = th.min(th.cat(self.critic(obs, demo_actions), dim=1), dim=1).values
                q_policy = th.min(th.cat(self.critic(obs, policy_actions), dim=1), dim=1).values
                keep = (q_demo > q_policy).float()
            squared = squared * keep
        return self.bc_weight * squared.mean()

    def _extra_actor_loss(self, batch_size: int) -> th.Tensor | None:
        if self.demonstrations is None or not self.bc_weight:
            return None
        return self.bc_loss(batch_size)

    def pretrain_actor(self, updates: int, batch_size: int = 256, fit_std: bool = False) -> list[float]:
        """Behaviour cloning of the actor's deterministic action on the demonstrations (no Q-filter:
        the critic knows nothing yet); returns the loss every 100 updates.

        ``fit_std``: also fit the actor's standard deviation to the demonstrations (their likelihood
        under the squashed Gaussian, the mean held fixed, weighted 0.01 against the squared error):
        otherwise it stays at its initial ~1 (pre-tanh), and SAC's first rollouts after pre-training
        scatter around the cloned action as widely as random ones."""
        losses = []
        self.policy.set_training_mode(True)
        for step in range(updates):
            obs, demo_actions = self.demonstrations.batch(batch_size)
            if fit_std:
                mean, log_std, _ = self.actor.get_action_dist_params(obs)
                loss = ((th.tanh(mean) - demo_actions) ** 2).sum(dim=1).mean()
                spread = self.actor.action_dist.proba_distribution(mean.detach(), log_std)
                loss = loss - STD_FIT_WEIGHT * spread.log_prob(demo_actions).mean()
            else:
                loss = ((self._deterministic_actions(obs) - demo_actions) ** 2).sum(dim=1).mean()
            self.actor.optimizer.zero_grad()
            loss.backward()
            self.actor.optimizer.step()
            if step % 100 == 0 or step == updates - 1:
                losses.append(float(loss.detach()))
        self.policy.set_training_mode(False)
        return losses


__all__ = ["DemoSAC", "Demonstrations", "ACTION_LIMIT"]
