"""Demonstrations in the actor's loss: SAC from demonstrations with a Q-filtered BC term.

Plain SAC on ToolShape-v0 drove the fingers to one end of the hinge range for every goal
within 2,500 to 5,000 steps in every variant tried here (effort on/off, HER, gamma 0.9,
plain SB3 SAC, smoother latents, a 3x action scale, a pre-filled buffer, no termination on
drops; ``analysis/low-level-ablation/README.md``). The likely cause: the action is a
relative joint change, so the loop integrates any bias of the actor into a drift to a
joint limit, and one step's action moves the latent by less than the perception's
frame-to-frame jitter, so the critic's action gradient is mostly noise. Demonstrations (any dataset of this task, e.g. the scripted synergy controller's,
``hingelab eval low --baseline synergy``) anchor the actor as in Nair et al., "Overcoming
Exploration in RL with Demonstrations" (2018):

    actor_loss = SAC actor loss + weight * mean_demo( [Q(s, a_demo) > Q(s, pi(s))] ||pi(s) - a_demo||^2 )

where pi(s) is the actor's deterministic action (tanh of its mean). The Q-filter drops the
term wherever the critic already prefers the policy's action, so SAC can improve on the
demonstrator; ``weight=0`` is plain SAC. ``pretrain_actor`` fits pi to the demonstrations
(behaviour cloning) before the first online step, so training starts from the
demonstrator instead of from noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch as th

ACTION_LIMIT = 0.97  # demo actions at the +-1 bound are fitted as this (tanh never reaches 1)


@dataclass
class DemoBC:
    """Demonstration (obs, action) pairs as float32 tensors and the BC term's weight."""

    observations: dict[str, th.Tensor]  # key -> (N, ...) as the policy's observation space
    actions: th.Tensor  # (N, A) in [-1, 1]
    weight: float
    q_filter: bool = True

    @classmethod
    def from_transitions(cls, transitions, weight: float, q_filter: bool = True) -> "DemoBC":
        obs = transitions.observations
        obs = obs if isinstance(obs, dict) else {"observation": obs}
        return cls({k: th.as_tensor(np.asarray(v), dtype=th.float32) for k, v in obs.items()},
                   th.as_tensor(np.clip(transitions.actions, -ACTION_LIMIT, ACTION_LIMIT), dtype=th.float32),
                   float(weight), q_filter)

    def __len__(self) -> int:
        return len(self.actions)

    def batch(self, batch_size: int) -> tuple[dict[str, th.Tensor], th.Tensor]:
        idx = th.from_numpy(np.random.randint(0, len(self), size=batch_size))
        return {k: v.index_select(0, idx) for k, v in self.observations.items()}, self.actions.index_select(0, idx)

    def loss(self, model, batch_size: int) -> th.Tensor:
        """The weighted, Q-filtered BC term for one actor update of ``model`` (an SB3 SAC)."""
        obs, demo_actions = self.batch(batch_size)
        mean, _, _ = model.actor.get_action_dist_params(obs)
        policy_actions = th.tanh(mean)
        squared = ((policy_actions - demo_actions) ** 2).sum(dim=1)
        if self.q_filter:
            with th.no_grad():
                q_demo = th.min(th.cat(model.critic(obs, demo_actions), dim=1), dim=1).values
                q_policy = th.min(th.cat(model.critic(obs, policy_actions), dim=1), dim=1).values
                keep = (q_demo > q_policy).float()
            squared = squared * keep
        return self.weight * squared.mean()


def pretrain_actor(model, demo: DemoBC, updates: int, batch_size: int = 256) -> list[float]:
    """Behaviour cloning of the actor's deterministic action on the demonstrations (no Q-filter:
    the critic knows nothing yet); returns the loss every 100 updates."""
    losses = []
    model.policy.set_training_mode(True)
    for step in range(updates):
        obs, demo_actions = demo.batch(batch_size)
        mean, _, _ = model.actor.get_action_dist_params(obs)
        loss = ((th.tanh(mean) - demo_actions) ** 2).sum(dim=1).mean()
        model.actor.optimizer.zero_grad()
        loss.backward()
        model.actor.optimizer.step()
        if step % 100 == 0 or step == updates - 1:
            losses.append(float(loss.detach()))
    model.policy.set_training_mode(False)
    return losses


__all__ = ["DemoBC", "pretrain_actor"]
