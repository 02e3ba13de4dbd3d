"""Faster SAC gradient updates on CPU while staying on stable-baselines3.

Where SB3's ``SAC.train()`` spends its time on this 2-core machine (batch 256, 2 x 256 ReLU
actor and twin critics, Dict observations) and what each change here buys is written up in
``analysis/bench/history/sac_updates.md``. In short:

- ``configure_torch`` stops glibc from handing the ~256 KB activation buffers back to the
  kernel after every free (``mallopt``): each fresh buffer otherwise costs its page faults
  again, which in a VM makes small activations far slower (``training.torch_process``).
- ``FastSAC`` is ``stable_baselines3.SAC`` with the same update, op for op, minus waste:
  fused Adam, no critic weight gradients in the actor loss (they were zeroed unused), critic
  features computed once per step, the squashed-Gaussian math without building a
  ``torch.distributions.Normal``, a ``_foreach`` Polyak update, losses logged once per
  ``train()`` call instead of four ``.item()`` per step, and a replay sampler that gathers
  with ``index_select`` from zero-copy torch views of the buffer's numpy arrays (same
  ``np.random`` draws as SB3, so the same seed gives the same batches).

``FastSAC`` saves with SB3's ``save`` and the file loads as plain ``SAC`` too.

Measured against bare SB3 ``SAC`` by ``hingelab bench sac`` (``hingelab.bench.sac``), which writes
``analysis/bench/sac.md``. Variants that change the algorithm (``hingelab.learners.sac.demo_sac.DemoSAC``)
subclass it and add their loss through ``_extra_actor_loss``.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any

import numpy as np
import torch as th
import torch.nn.functional as F
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import DictReplayBuffer, ReplayBuffer
from stable_baselines3.common.type_aliases import DictReplayBufferSamples, ReplayBufferSamples
from stable_baselines3.common.utils import polyak_update

from hingelab.learners.sac.compiled_update import CompiledSACUpdate, train_compiled
from hingelab.learners.sac.fused_update import FusedSACUpdate, train_fused
from hingelab.learners.sac.overlap import OverlappedLearning
from hingelab.training.torch_process import configure_torch  # noqa: F401  (re-exported: the bench applies it)

#: The ways ``FastSAC`` can run one gradient step (the same algorithm each).
UPDATES = ("eager", "compiled", "fused")

#: Every speed-up ``FastSAC`` applies by default; pass a subset as ``speedups=`` to ablate.
ALL_SPEEDUPS = frozenset(
    {
        "sampler",  # index_select from zero-copy views of the buffer instead of numpy fancy indexing + copies
        "actor_math",  # squashed Gaussian inline, no torch.distributions.Normal (arg validation)
        "critic_no_weight_grad",  # actor loss does not compute critic weight gradients
        "critic_features_once",  # parameter-free critic feature extractor run once per step
        "foreach_polyak",  # two _foreach ops instead of two ops per parameter
        "deferred_logging",  # losses stacked and averaged once per train() call
        "inplace_relu",  # ReLU right after a Linear in the MLPs writes in place: one fresh buffer less each
    }
)



class _TorchViewSampler:
    """Samples a plain ``ReplayBuffer``/``DictReplayBuffer`` like SB3 does, but in torch.

    Draws exactly the same ``np.random.randint`` calls as ``ReplayBuffer.sample`` +
    ``_get_samples`` (so batches are identical for the same NumPy seed) and gathers rows with
    ``index_select`` from ``torch.from_numpy`` views that share memory with the buffer's arrays,
    so later ``add()`` calls are seen without copying.
    """

    def __init__(self, buffer: ReplayBuffer):
        self.buffer = buffer
        rows = buffer.buffer_size * buffer.n_envs

        def view(array: np.ndarray) -> th.Tensor:
            return th.from_numpy(array).reshape(rows, *array.shape[2:])

        self.is_dict = isinstance(buffer, DictReplayBuffer)
        if self.is_dict:
            self.obs = {k: view(v) for k, v in buffer.observations.items()}
            self.next_obs = {k: view(v) for k, v in buffer.next_observations.items()}
        else:
            self.obs = view(buffer.observations)
            self.next_obs = view(buffer.next_observations)
        self.actions = view(buffer.actions)
        self.rewards = view(buffer.rewards)
        self.dones = view(buffer.dones)
        self.timeouts = view(buffer.timeouts)
        self._arrays = self._array_ids(buffer)

    @staticmethod
    def supports(buffer: Any, vec_normalize_env: Any) -> bool:
        return (
            type(buffer) in (ReplayBuffer, DictReplayBuffer)
            and not buffer.optimize_memory_usage
            and vec_normalize_env is None
            and th.device(buffer.device).type == "cpu"
        )

    @staticmethod
    def _array_ids(buffer: ReplayBuffer) -> tuple[int, ...]:
        obs = buffer.observations
        obs_ids = tuple(id(v) for v in obs.values()) if isinstance(obs, dict) else (id(obs),)
        return (*obs_ids, id(buffer.actions), id(buffer.rewards), id(buffer.dones))

    def still_valid(self, buffer: Any) -> bool:
        return buffer is self.buffer and self._array_ids(buffer) == self._arrays

    def sample(self, batch_size: int) -> ReplayBufferSamples | DictReplayBufferSamples:
        b = self.buffer
        upper_bound = b.buffer_size if b.full else b.pos
        batch_inds = np.random.randint(0, upper_bound, size=batch_size)
        env_indices = np.random.randint(0, high=b.n_envs, size=(len(batch_inds),))
        idx = th.from_numpy(batch_inds * b.n_envs + env_indices)

        def take(t: th.Tensor) -> th.Tensor:
            return t.index_select(0, idx)

        if self.is_dict:
            obs = {k: take(v) for k, v in self.obs.items()}
            next_obs = {k: take(v) for k, v in self.next_obs.items()}
        else:
            obs, next_obs = take(self.obs), take(self.next_obs)
        dones = (take(self.dones) * (1 - take(self.timeouts))).reshape(-1, 1)
        rewards = take(self.rewards).reshape(-1, 1)
        cls = DictReplayBufferSamples if self.is_dict else ReplayBufferSamples
        return cls(observations=obs, actions=take(self.actions), next_observations=next_obs, dones=dones,
                   rewards=rewards)


class FastSAC(OverlappedLearning, SAC):
    """``stable_baselines3.SAC`` with a faster ``train()``; same algorithm and arguments. With
    ``overlap`` set, ``learn`` runs the updates while the envs step (``hingelab.learners.sac.overlap``).

    Extra argument ``speedups``: a subset of ``ALL_SPEEDUPS`` (default: all); ``update``: ``"eager"``
    (default), ``"compiled"``, each gradient step as one ``torch.compile``d function
    (``hingelab.learners.sac.compiled_update``), or ``"fused"``, the gradients written out by hand
    into buffers made once (``hingelab.learners.sac.fused_update``); the same algorithm. Adam is fused
    unless ``policy_kwargs["optimizer_kwargs"]`` says otherwise. gSDE and replay buffers other
    than plain ``ReplayBuffer``/``DictReplayBuffer`` (HER, n-step, memory-optimized,
    VecNormalize) fall back to SB3's own code for the part they change (sampling, noise).
    """

    def __init__(self, policy: Any, env: Any, *args: Any, speedups: Iterable[str] | None = None,
                 update: str = "eager", **kwargs: Any):
        if update not in UPDATES:
            raise ValueError(f"update must be one of {', '.join(repr(u) for u in UPDATES)}, not {update!r}")
        self.update = update
        policy_kwargs = dict(kwargs.pop("policy_kwargs", None) or {})
        optimizer_kwargs = dict(policy_kwargs.get("optimizer_kwargs") or {})
        optimizer_kwargs.setdefault("fused", True)
        policy_kwargs["optimizer_kwargs"] = optimizer_kwargs
        kwargs["policy_kwargs"] = policy_kwargs
        self.speedups = ALL_SPEEDUPS if speedups is None else frozenset(speedups)
        unknown = self.speedups - ALL_SPEEDUPS
        if unknown:
            raise ValueError(f"unknown speedups {sorted(unknown)}; known: {sorted(ALL_SPEEDUPS)}")
        super().__init__(policy, env, *args, **kwargs)
        if update != "eager":
            problem = (CompiledSACUpdate if update == "compiled" else FusedSACUpdate).check(self)
            if problem:
                raise ValueError(f"update={update!r} does not support this model: {problem}")

    def _setup_model(self) -> None:
        super()._setup_model()
        if self.ent_coef_optimizer is not None:
            fused = bool(self.policy_kwargs.get("optimizer_kwargs", {}).get("fused", False))
            self.ent_coef_optimizer = th.optim.Adam([self.log_ent_coef], lr=self.lr_schedule(1), fused=fused)
        if "inplace_relu" in self.speedups:
            _relu_in_place_after_linear(self.policy)

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "_fast_sampler", "_compiled_update", "_fused_update"]

    # --- pieces of one update -------------------------------------------------------------

    def _sample(self, batch_size: int) -> Any:
        if "sampler" in self.speedups and _TorchViewSampler.supports(self.replay_buffer, self._vec_normalize_env):
            sampler = getattr(self, "_fast_sampler", None)
            if sampler is None or not sampler.still_valid(self.replay_buffer):
                sampler = self._fast_sampler = _TorchViewSampler(self.replay_buffer)  # type: ignore[arg-type]
            return sampler.sample(batch_size)
        return self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]

    def _action_log_prob(self, obs: Any) -> tuple[th.Tensor, th.Tensor]:
        """Same ops, same order and same RNG draw as ``Actor.action_log_prob`` without gSDE."""
        if self.use_sde or "actor_math" not in self.speedups:
            actions, log_prob = self.actor.action_log_prob(obs)
            return actions, log_prob
        actions, log_prob, _ = self._action_log_prob_mean(obs)
        return actions, log_prob

    def _action_log_prob_mean(self, obs: Any) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``_action_log_prob``'s actions and log-probabilities and the Gaussian's mean they came from (one
        forward of the actor for a loss that needs the mean too)."""
        mean, log_std, _ = self.actor.get_action_dist_params(obs)
        std = th.ones_like(mean) * log_std.exp()
        gaussian = mean + th.empty(mean.shape, dtype=mean.dtype, device=mean.device).normal_() * std
        actions = th.tanh(gaussian)
        log_prob = -((gaussian - mean) ** 2) / (2 * std**2) - std.log() - math.log(math.sqrt(2 * math.pi))
        log_prob = log_prob.sum(dim=1)
        log_prob = log_prob - th.sum(th.log(1 - actions**2 + self.actor.action_dist.epsilon), dim=1)
        return actions, log_prob, mean

    def _critic_features(self, obs: Any) -> th.Tensor | None:
        """Critic features of ``obs`` when they can be reused within a step, else None.

        Only for a parameter-free, unshared extractor (Flatten, CombinedExtractor of Flattens):
        with parameters, SB3 recomputes them after the critic step, and so must we.
        """
        critic = self.critic
        if "critic_features_once" not in self.speedups or critic.share_features_extractor:
            return None
        if any(True for _ in critic.features_extractor.parameters()):
            return None
        with th.no_grad():
            return critic.extract_features(obs, critic.features_extractor)

    def _q_values(self, critic: Any, obs: Any, features: th.Tensor | None, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        if features is None:
            return critic(obs, actions)
        qvalue_input = th.cat([features, actions], dim=1)
        return tuple(q_net(qvalue_input) for q_net in critic.q_networks)

    def _extra_actor_loss(self, batch_size: int) -> th.Tensor | None:
        """A term a variant adds to the actor loss of each update (None: plain SAC)."""
        return None

    # --- the update -------------------------------------------------------------------------

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        update = getattr(self, "update", "eager")  # (models saved before the option have none)
        if update == "compiled":
            train_compiled(self, gradient_steps, batch_size)
            return
        if update == "fused":
            train_fused(self, gradient_steps, batch_size)
            return
        self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers += [self.ent_coef_optimizer]
        self._update_learning_rate(optimizers)

        actor_ids = {id(p) for p in self.actor.parameters()}
        critic_only = [p for p in self.critic.parameters() if id(p) not in actor_ids and p.requires_grad]
        skip_critic_grads = "critic_no_weight_grad" in self.speedups
        critic_params = list(self.critic.parameters())
        target_params = list(self.critic_target.parameters())
        foreach_polyak = "foreach_polyak" in self.speedups
        deferred = "deferred_logging" in self.speedups

        ent_coef_losses: list[Any] = []
        ent_coefs: list[Any] = []
        actor_losses: list[Any] = []
        critic_losses: list[Any] = []

        def keep(values: list[Any], x: th.Tensor) -> None:
            values.append(x.detach() if deferred else x.item())

        for gradient_step in range(gradient_steps):
            replay_data = self._sample(batch_size)
            discounts = replay_data.discounts if replay_data.discounts is not None else self.gamma

            if self.use_sde:
                self.actor.reset_noise()

            actions_pi, log_prob = self._action_log_prob(replay_data.observations)
            log_prob = log_prob.reshape(-1, 1)

            ent_coef_loss = None
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = th.exp(self.log_ent_coef.detach())
                assert isinstance(self.target_entropy, float)
                ent_coef_loss = -(self.log_ent_coef * (log_prob + self.target_entropy).detach()).mean()
                keep(ent_coef_losses, ent_coef_loss)
            else:
                ent_coef = self.ent_coef_tensor
            keep(ent_coefs, ent_coef)

            if ent_coef_loss is not None and self.ent_coef_optimizer is not None:
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()

            with th.no_grad():
                next_actions, next_log_prob = self._action_log_prob(replay_data.next_observations)
                next_q_values = th.cat(
                    self._q_values(self.critic_target, replay_data.next_observations, None, next_actions), dim=1
                )
                next_q_values, _ = th.min(next_q_values, dim=1, keepdim=True)
                next_q_values = next_q_values - ent_coef * next_log_prob.reshape(-1, 1)
                target_q_values = replay_data.rewards + (1 - replay_data.dones) * discounts * next_q_values

            features = self._critic_features(replay_data.observations)
            current_q_values = self._q_values(self.critic, replay_data.observations, features, replay_data.actions)
            # SB3 writes 0.5 * sum(...): the leading 0 + x is exact, so this is the same number
            critic_loss = F.mse_loss(current_q_values[0], target_q_values)
            for current_q in current_q_values[1:]:
                critic_loss = critic_loss + F.mse_loss(current_q, target_q_values)
            critic_loss = 0.5 * critic_loss
            keep(critic_losses, critic_loss)

            self.critic.optimizer.zero_grad()
            critic_loss.backward()
            self.critic.optimizer.step()

            # SB3 lets the actor loss also fill the critic's .grad, which the next critic
            # zero_grad() throws away: skip computing it (the input gradient is still computed).
            if skip_critic_grads:
                for p in critic_only:
                    p.requires_grad_(False)
            try:
                q_values_pi = th.cat(self._q_values(self.critic, replay_data.observations, features, actions_pi), dim=1)
                min_qf_pi, _ = th.min(q_values_pi, dim=1, keepdim=True)
                actor_loss = (ent_coef * log_prob - min_qf_pi).mean()
                extra = self._extra_actor_loss(batch_size)
                if extra is not None:  # a variant's own term (hingelab.learners.sac.demo_sac.DemoSAC)
                    actor_loss = actor_loss + extra
                keep(actor_losses, actor_loss)
                self.actor.optimizer.zero_grad()
                actor_loss.backward()
            finally:
                if skip_critic_grads:
                    for p in critic_only:
                        p.requires_grad_(True)
            self.actor.optimizer.step()

            if gradient_step % self.target_update_interval == 0:
                self._polyak(critic_params, target_params, foreach_polyak)

        self._record_update(gradient_steps, ent_coefs, actor_losses, critic_losses, ent_coef_losses)

    def _record_update(self, gradient_steps: int, ent_coefs, actor_losses, critic_losses, ent_coef_losses) -> None:
        """Count the updates and log their mean losses (as SB3's ``train`` does; empty lists are not logged)."""
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/ent_coef", _mean(ent_coefs))
        if actor_losses:
            self.logger.record("train/actor_loss", _mean(actor_losses))
        self.logger.record("train/critic_loss", _mean(critic_losses))
        if ent_coef_losses:
            self.logger.record("train/ent_coef_loss", _mean(ent_coef_losses))

    def _polyak(self, params: list[th.Tensor], targets: list[th.Tensor], foreach: bool) -> None:
        """``polyak_update`` of SB3 (mul_ then add with alpha), for parameters and BN stats."""

        if not foreach:
            polyak_update(params, targets, self.tau)
            polyak_update(self.batch_norm_stats, self.batch_norm_stats_target, 1.0)
            return
        with th.no_grad():
            target_data = [t.data for t in targets]
            th._foreach_mul_(target_data, 1 - self.tau)
            th._foreach_add_(target_data, [p.data for p in params], alpha=self.tau)
            if self.batch_norm_stats:
                stats_target = [t.data for t in self.batch_norm_stats_target]
                th._foreach_mul_(stats_target, 0.0)
                th._foreach_add_(stats_target, [s.data for s in self.batch_norm_stats], alpha=1.0)


def _relu_in_place_after_linear(module: th.nn.Module) -> None:
    """Set ``inplace`` on every ``nn.ReLU`` that directly follows an ``nn.Linear`` in a Sequential.

    Linear's backward needs its input, not its output, so overwriting the output is safe and the
    values are unchanged; it saves writing a fresh (256, 256) buffer per layer, which is slow here.
    Not saved with the model (policy_kwargs still say ``nn.ReLU``); ``_setup_model`` redoes it.
    """
    for sequential in module.modules():
        if isinstance(sequential, th.nn.Sequential):
            layers = list(sequential)
            for previous, layer in zip(layers, layers[1:]):
                if isinstance(layer, th.nn.ReLU) and isinstance(previous, th.nn.Linear):
                    layer.inplace = True


def _mean(values: list[Any]) -> float:
    if values and isinstance(values[0], th.Tensor):
        return float(th.stack(values).to(th.float64).mean().item())
    return float(np.mean(values))
