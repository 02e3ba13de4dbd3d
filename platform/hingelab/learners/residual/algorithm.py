"""``ResidualSAC``: FastSAC's update for the residual policy, with the recipes of online RL from a prior.

What differs from FastSAC (``hingelab.learners.sac.fast_sac``), each for a reason the runs of plain SAC
from the privileged buffer showed (``analysis/high-level/``):

* **Acting with the policy from the first step.** SB3 acts uniformly at random until ``learning_starts``;
  here the policy acts from step 0 (the base plus the residual's bounded noise), so the first data are
  the prior's own rollouts (WSRL, Zhou et al. 2024), not random flailing that drops the tool.
* **Critic warm-up.** The actor and the temperature do not move until ``actor_start`` env steps: until
  then only the critics learn, on the prior's rollouts (and the demos), so the first actor gradient
  comes from a critic that has seen the task, not from an untrained one.
* **A critic ensemble** (``EnsembleCritic``, LayerNorm): the bootstrap target takes the minimum over a
  random subset of ``target_critics`` members (REDQ, Chen et al. 2021; RLPD, Ball et al. 2023), the
  actor the members' mean (``actor_q``: or their minimum, or mean minus standard deviation); several updates
  per env step (``gradient_steps``) are then stable.
* **The base proposes too** (``choose_by_q``, IBRL, Hu et al. 2024): the rollouts act with the residual's
  sample only where the critics' minimum Q of it beats that of the base's own action (residual 0), and the
  bootstrap target takes the better of the two at the next state, so the critic values what the base
  already achieves from the first update and a bad residual is not what the policy executes.
* **Or an advantage-weighted actor** (``actor_update="awr"``, AWAC, Nair et al. 2020): the actor fits the
  batch's own residuals weighted by their advantage under the critics, instead of following the critics'
  action gradient, which extrapolates where the data shows no action vary.
* **A pull back to the base** (``residual_penalty``): the actor's loss adds
  ``residual_penalty * mean|Q| * mean(tanh(mu)^2)``, the squared deterministic residual scaled by the
  batch's mean |Q| as TD3+BC scales its BC term (Fujimoto and Gu 2021). Adam takes steps of the learning
  rate's size whatever the gradient's, so without it a critic's small, noisy action gradients still walk
  the zero-initialized residual to its bounds within a few thousand updates; with it the residual moves
  only where the critic's gain outweighs the pull (a BC term toward the base: the base is residual 0).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F

from hingelab.learners.sac.fast_sac import FastSAC
from hingelab.policies.residual import ChooseByQ


class ResidualSAC(FastSAC):
    """FastSAC with policy-driven warm-up, a critic-only warm-up and an ensemble target (module doc)."""

    def __init__(self, *args: Any, actor_start: int = 0, target_critics: int = 2, residual_penalty: float = 0.0,
                 choose_by_q: bool = False, actor_q: str = "mean", actor_update: str = "gradient",
                 awr_temperature: float = 1.0, **kwargs: Any):
        if actor_q not in ("mean", "min", "lcb"):
            raise ValueError(f"actor_q is mean, min or lcb, not {actor_q!r}")
        if actor_update not in ("gradient", "awr"):
            raise ValueError(f"actor_update is gradient or awr, not {actor_update!r}")
        self.actor_q, self.actor_update, self.awr_temperature = actor_q, actor_update, float(awr_temperature)
        self.actor_start = int(actor_start)
        self.target_critics = int(target_critics)
        self.residual_penalty = float(residual_penalty)
        self.choose_by_q = bool(choose_by_q)
        super().__init__(*args, **kwargs)

    def chooser(self) -> ChooseByQ:
        """The choice between the base's and the residual's action by the current critics."""
        return ChooseByQ(self.critic.q_net, self.critic.n_critics, self.critic.scale)

    def _sample_action(self, learning_starts: int, action_noise=None, n_envs: int = 1):
        # the policy acts from the first step (SB3 would act uniformly at random before learning_starts)
        action, buffer_action = super()._sample_action(0, action_noise, n_envs)
        if self.choose_by_q:  # the base's action where the critics prefer it (stored as residual 0)
            wins = self.chooser().wins(th.as_tensor(self._last_obs, dtype=th.float32),
                                       th.as_tensor(buffer_action, dtype=th.float32)).numpy()
            action = np.where(wins[:, None], action, 0.0).astype(action.dtype)
            buffer_action = np.where(wins[:, None], buffer_action, 0.0).astype(buffer_action.dtype)
        return action, buffer_action

    def actor_value(self, q: th.Tensor) -> th.Tensor:
        """What the actor maximizes, from the members' Q of its action (E, B, 1): their mean, minimum, or mean
        minus their standard deviation (a lower confidence bound: the actor does not follow one member's error)."""
        if self.actor_q == "min" or (self.actor_q == "lcb" and q.shape[0] < 2):
            return q.min(dim=0).values
        if self.actor_q == "lcb":
            return q.mean(dim=0) - q.std(dim=0)
        return q.mean(dim=0)

    def awr_weights(self, advantage: th.Tensor) -> th.Tensor:
        """Per-sample weights of the advantage-weighted update: ``B * softmax(A / (T * mean|A|))`` over the batch
        (AWAC's normalization; the advantage in units of its batch mean so the temperature ``T`` does not
        depend on the reward's scale)."""
        scale = self.awr_temperature * advantage.abs().mean().clamp_min(1e-6)
        return th.softmax(advantage / scale, dim=0) * advantage.shape[0]

    def _awr_step(self, data) -> th.Tensor:
        """One advantage-weighted actor update (AWAC, Nair et al. 2020): maximize the log-likelihood of the
        batch's own residuals (rollouts and demos), each weighted by how much the critics value it above the
        policy's deterministic residual. Only actions that were taken are valued: the actor never follows the
        critics' gradient into actions no data shows."""
        obs = data.observations
        mean, log_std, _ = self.actor.get_action_dist_params(obs)
        taken = data.actions.clamp(-1 + 1e-3, 1 - 1e-3)  # the demos' residuals may sit on the bound
        pre_tanh = th.atanh(taken)
        # the Gaussian's log-likelihood of the pre-tanh residual (tanh's correction does not depend on the actor)
        log_lik = (-((pre_tanh - mean) ** 2) / (2 * th.exp(2 * log_std)) - log_std).sum(dim=1)
        with th.no_grad():
            q_taken = self.actor_value(self.critic.q_values(obs, data.actions)).squeeze(1)
            q_policy = self.actor_value(self.critic.q_values(obs, th.tanh(mean))).squeeze(1)
            weights = self.awr_weights(q_taken - q_policy)
        actor_loss = -(weights * log_lik).mean()
        if self.residual_penalty:
            actor_loss = actor_loss + self.residual_penalty * (th.tanh(mean) ** 2).mean()
        self.actor.optimizer.zero_grad()
        actor_loss.backward()
        self.actor.optimizer.step()
        return actor_loss.detach()

    def _q_values(self, critic: Any, obs: Any, features: Any, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        return critic(obs, actions)  # the ensemble rebuilds the executed action from obs: never skip its forward

    @property
    def actor_moves(self) -> bool:
        """Whether the actor and the temperature update now (after the critic-only warm-up)."""
        return self.num_timesteps >= self.actor_start and not getattr(self, "_critic_only", False)

    def pretrain_critic(self, updates: int, batch_size: int) -> None:
        """``updates`` critic-only updates on what the replay buffer holds (before the first env step: the
        demos), the actor and the temperature untouched whatever ``actor_start`` says."""
        self._critic_only = True
        try:
            self.train(gradient_steps=updates, batch_size=batch_size)
        finally:
            self._critic_only = False

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)
        actor_moves = self.actor_moves
        critic_params = list(self.critic.parameters())
        target_params = list(self.critic_target.parameters())
        members = self.critic.n_critics
        subset = min(self.target_critics, members)
        ent_coefs, actor_losses, critic_losses, ent_coef_losses = [], [], [], []

        for gradient_step in range(gradient_steps):
            data = self._sample(batch_size)
            discounts = data.discounts if data.discounts is not None else self.gamma
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = th.exp(self.log_ent_coef.detach())
            else:
                ent_coef = self.ent_coef_tensor
            ent_coefs.append(ent_coef.detach())

            with th.no_grad():
                next_actions, next_log_prob = self._action_log_prob(data.next_observations)
                chosen = None
                if subset < members:  # REDQ: the minimum over a random subset of members (only theirs computed)
                    chosen = th.from_numpy(np.random.choice(members, subset, replace=False))
                next_q = self.critic_target.q_values(data.next_observations, next_actions, chosen)  # (subset, B, 1)
                next_q = next_q.min(dim=0).values
                if self.choose_by_q:  # the better of the residual's and the base's action at the next state
                    base_q = self.critic_target.q_values(data.next_observations, th.zeros_like(next_actions), chosen)
                    next_q = th.maximum(next_q, base_q.min(dim=0).values)
                next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = data.rewards + (1 - data.dones) * discounts * next_q

            current_q = self.critic.q_values(data.observations, data.actions)  # (E, B, 1)
            critic_loss = 0.5 * members * F.mse_loss(current_q, target_q.unsqueeze(0).expand_as(current_q))
            critic_losses.append(critic_loss.detach())
            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            if actor_moves and self.actor_update == "awr":
                actor_losses.append(self._awr_step(data))
            elif actor_moves:
                actions_pi, log_prob, mean = self._action_log_prob_mean(data.observations)
                log_prob = log_prob.reshape(-1, 1)
                if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                    ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                    ent_coef_losses.append(ent_coef_loss.detach())
                    self.ent_coef_optimizer.zero_grad()
                    ent_coef_loss.backward()
                    self.ent_coef_optimizer.step()
                for p in critic_params:  # the actor's loss needs the input gradient only
                    p.requires_grad_(False)
                try:
                    q_pi = self.actor_value(self.critic.q_values(data.observations, actions_pi))
                    actor_loss = (ent_coef * log_prob - q_pi).mean()
                    if self.residual_penalty:  # the mean of the same forward as actions_pi
                        pull = (th.tanh(mean) ** 2).mean()
                        actor_loss = actor_loss + self.residual_penalty * q_pi.detach().abs().mean() * pull
                    extra = self._extra_actor_loss(batch_size)
                    if extra is not None:
                        actor_loss = actor_loss + extra
                    actor_losses.append(actor_loss.detach())
                    self.actor.optimizer.zero_grad()
                    actor_loss.backward()
                finally:
                    for p in critic_params:
                        p.requires_grad_(True)
                self.actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                self._polyak(critic_params, target_params, True)

        self._record_update(gradient_steps, ent_coefs, actor_losses, critic_losses, ent_coef_losses)


__all__ = ["ResidualSAC"]
