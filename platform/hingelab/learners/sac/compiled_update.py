"""One SAC gradient step as a single function: ``FastSAC(update="compiled")``.

The temperature, critic and actor losses, their gradients (``torch.func.grad_and_value``) and
their three Adam steps are written as one pure function of the parameters, the optimizer state
and the batch, which ``torch.compile`` turns into one graph (inductor fuses the elementwise work:
the squashed Gaussian, the losses, the Adam updates) and which writes its results back into the
model's parameters and the model's own ``torch.optim.Adam`` states. So saving, loading and
switching back to the eager update keep working, and the model still loads as plain SB3 ``SAC``.

Same algorithm as ``stable_baselines3.SAC.train`` up to floating-point order, step for step:

1. the actor's squashed Gaussian on the observations (``actions_pi``, ``log_prob``);
2. the temperature: ``-(log_alpha * (log_prob + target_entropy)).mean()``, one Adam step;
   its gradient, ``-mean(log_prob + target_entropy)``, is written out instead of backpropagated;
3. the critic target from the next observations (the actor's action and log-probability, the
   minimum of the target critics, ``ent_coef`` from before step 2); the twin-critic loss
   ``0.5 * sum_k mse(q_k, target)``, one Adam step;
4. the actor loss ``(ent_coef * log_prob - min_k q_k(obs, actions_pi)).mean()`` through the
   critics *after* their step (their weights held constant), one Adam step;
5. the Polyak update of the target critics (every ``target_update_interval`` steps, outside).

The Gaussian noise of steps 1 and 3 is drawn outside the compiled graph with the same calls in
the same order as the eager update, so the same seed gives the same noise and the same batches.
``log_prob`` uses ``noise`` for ``(gaussian - mean) / std`` and ``log_std`` for ``log(std)``:
the same value and gradient as SB3's expression, in a different floating-point order.

Supported: what ``FastSAC``'s eager update covers except gSDE, a variant's extra actor loss
(``_extra_actor_loss``), feature extractors with parameters, a fixed ``ent_coef`` (the
temperature must be learned) and optimizers other than ``torch.optim.Adam`` without weight decay;
``CompiledSACUpdate.check`` names what a model lacks.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import torch as th
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN
from torch import nn

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
_ACTIVATIONS: dict[type, Callable[[th.Tensor], th.Tensor]] = {nn.ReLU: th.relu, nn.Tanh: th.tanh}


def _mlp_layout(sequential: nn.Sequential) -> tuple[list[nn.Linear], list[Callable[[th.Tensor], th.Tensor] | None]]:
    """The Linear layers of an MLP and the activation after each (None: no activation)."""
    linears: list[nn.Linear] = []
    activations: list[Callable[[th.Tensor], th.Tensor] | None] = []
    for layer in sequential:
        if isinstance(layer, nn.Linear):
            linears.append(layer)
            activations.append(None)
        elif type(layer) in _ACTIVATIONS and linears and activations[-1] is None:
            activations[-1] = _ACTIVATIONS[type(layer)]
        else:
            raise ValueError(f"the compiled SAC update supports MLPs of Linear, ReLU and Tanh, not {layer}")
    return linears, activations


def _mlp(x: th.Tensor, params: Sequence[th.Tensor], activations: Sequence[Any]) -> th.Tensor:
    """An MLP from its flat ``[w0, b0, w1, b1, ...]`` parameters."""
    return _mlp_from(x, params, activations, 0)


def _adam(params: list[th.Tensor], grads: list[th.Tensor], exp_avgs: list[th.Tensor], exp_avg_sqs: list[th.Tensor],
          step: th.Tensor, lr: th.Tensor, beta1: float, beta2: float, eps: float
          ) -> tuple[list[th.Tensor], list[th.Tensor], list[th.Tensor], th.Tensor]:
    """``torch.optim.Adam`` (no weight decay, amsgrad or maximize), out of place: new params, moments and step."""
    step = step + 1
    bias_correction1 = 1 - beta1**step
    bias_correction2_sqrt = (1 - beta2**step).sqrt()
    step_size = lr / bias_correction1
    new_params, new_avgs, new_sqs = [], [], []
    for p, g, m, v in zip(params, grads, exp_avgs, exp_avg_sqs, strict=True):
        m = m.lerp(g, 1 - beta1)
        v = v * beta2 + (1 - beta2) * g * g
        new_params.append(p - step_size * m / (v.sqrt() / bias_correction2_sqrt + eps))
        new_avgs.append(m)
        new_sqs.append(v)
    return new_params, new_avgs, new_sqs, step


def _critics(x: th.Tensor, params: Sequence[Sequence[th.Tensor]], activations: Sequence[Any]) -> th.Tensor:
    """The critics' values of ``x``, (B, n_critics): their first layers, which read the same input, as one
    matmul of their stacked weights; the rest one critic at a time."""
    first = th.nn.functional.linear(x, th.cat([ps[0] for ps in params]), th.cat([ps[1] for ps in params]))
    if activations[0] is not None:
        first = activations[0](first)
    hidden = first.split([ps[0].shape[0] for ps in params], dim=1)
    return th.cat([_mlp_from(h, ps, activations, 1) for h, ps in zip(hidden, params)], dim=1)


def _mlp_from(x: th.Tensor, params: Sequence[th.Tensor], activations: Sequence[Any], start: int) -> th.Tensor:
    """Layers ``start`` on of an MLP from its flat ``[w0, b0, w1, b1, ...]`` parameters."""
    for i in range(start, len(activations)):
        x = th.nn.functional.linear(x, params[2 * i], params[2 * i + 1])
        if activations[i] is not None:
            x = activations[i](x)
    return x


class CompiledSACUpdate:
    """The gradient step of one ``FastSAC`` model as one (compiled) function.

    ``step(replay_data)`` runs steps 1-4 of the module docstring on one batch, in place on the
    model's parameters and optimizer states, and returns the detached losses and ``ent_coef``.
    ``compile=False`` runs the same function without ``torch.compile`` (for tests and debugging).
    """

    def __init__(self, model: Any, compile: bool = True):
        problem = self.check(model)
        if problem:
            raise ValueError(f"the compiled SAC update does not support this model: {problem}")
        self.model = model
        actor, critic = model.actor, model.critic
        latent, self._latent_acts = _mlp_layout(actor.latent_pi)
        self._actor_modules = [*latent, actor.mu, actor.log_std]
        self._critic_acts = _mlp_layout(critic.q_networks[0])[1]
        self._epsilon = float(actor.action_dist.epsilon)
        self._fn = th.compile(self._update, fullgraph=True, dynamic=False) if compile else self._update

    @staticmethod
    def check(model: Any) -> str | None:
        """Why the compiled update cannot run ``model`` (None: it can)."""
        if model.use_sde:
            return "gSDE"
        if model.ent_coef_optimizer is None:
            return "a fixed ent_coef (the compiled update learns the temperature)"
        if type(model)._extra_actor_loss.__qualname__ != "FastSAC._extra_actor_loss":
            return f"{type(model).__name__} adds its own actor loss (_extra_actor_loss)"
        for name, module in (("actor", model.actor), ("critic", model.critic)):
            if any(True for _ in module.features_extractor.parameters()):
                return f"the {name}'s features extractor has parameters"
        optimizers = [model.actor.optimizer, model.critic.optimizer, model.ent_coef_optimizer]
        for optimizer in optimizers:
            if type(optimizer) is not th.optim.Adam or len(optimizer.param_groups) != 1:
                return f"optimizer {type(optimizer).__name__} (only torch.optim.Adam with one param group)"
            group = optimizer.param_groups[0]
            if group["weight_decay"] or group["amsgrad"] or group["maximize"]:
                return "Adam with weight_decay, amsgrad or maximize"
        critic_params = {id(p) for p in model.critic.parameters()}
        if any(id(p) in critic_params for p in model.actor.parameters()):
            return "actor and critic share parameters"
        try:
            _mlp_layout(model.actor.latent_pi)
            layouts = {tuple((type(layer), getattr(layer, "weight", th.empty(0)).shape) for layer in q)
                       for q in model.critic.q_networks}
            if len(layouts) != 1:
                return "critics of different shapes"
            _mlp_layout(model.critic.q_networks[0])
        except ValueError as error:
            return str(error)
        return None

    # --- the parameters and optimizer states, read fresh each step (load() replaces states) ---

    def _actor_params(self) -> list[th.Tensor]:
        return [t for layer in self._actor_modules for t in (layer.weight, layer.bias)]

    @staticmethod
    def _net_params(q_networks: Sequence[nn.Sequential]) -> list[list[th.Tensor]]:
        return [[t for layer in q if isinstance(layer, nn.Linear) for t in (layer.weight, layer.bias)]
                for q in q_networks]

    @staticmethod
    def _adam_state(optimizer: th.optim.Adam, params: list[th.Tensor]) -> tuple[list[th.Tensor], list[th.Tensor],
                                                                                list[th.Tensor], th.Tensor, tuple]:
        """The optimizer's moments and step counts (created as ``Adam`` would on its first step) and its lr."""
        group = optimizer.param_groups[0]
        avgs, sqs, steps = [], [], []
        for p in params:
            state = optimizer.state[p]
            if not state:
                state["step"] = th.tensor(0.0, dtype=th.float32)
                state["exp_avg"] = th.zeros_like(p, memory_format=th.preserve_format)
                state["exp_avg_sq"] = th.zeros_like(p, memory_format=th.preserve_format)
            avgs.append(state["exp_avg"])
            sqs.append(state["exp_avg_sq"])
            steps.append(state["step"])
        lr = th.tensor(float(group["lr"]))
        return avgs, sqs, steps, lr, (float(group["betas"][0]), float(group["betas"][1]), float(group["eps"]))

    # --- one step -------------------------------------------------------------------------------

    def step(self, replay_data: Any, discounts: Any) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """One update on ``replay_data``; returns (ent_coef_loss, ent_coef, critic_loss, actor_loss), detached."""
        model = self.model
        actor = model.actor
        obs, next_obs = batch_features(model, replay_data)
        shape = (obs.shape[0], actor.mu.out_features)
        noise_pi = th.empty(shape, dtype=obs.dtype).normal_()  # the eager update's two draws, in its order
        noise_next = th.empty(shape, dtype=obs.dtype).normal_()
        discounts = th.as_tensor(discounts, dtype=obs.dtype)

        actor_params = self._actor_params()
        critic_params = self._net_params(model.critic.q_networks)
        target_params = self._net_params(model.critic_target.q_networks)
        flat_critic = [t for ps in critic_params for t in ps]
        log_alpha = model.log_ent_coef
        states = (self._adam_state(actor.optimizer, actor_params),
                  self._adam_state(model.critic.optimizer, flat_critic),
                  self._adam_state(model.ent_coef_optimizer, [log_alpha]))
        return self._fn(actor_params, critic_params, target_params, log_alpha, states, obs,
                        replay_data.actions, next_obs, replay_data.rewards, replay_data.dones, discounts,
                        noise_pi, noise_next, float(model.target_entropy))

    def _actor(self, params: Sequence[th.Tensor], obs: th.Tensor, noise: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """Squashed-Gaussian actions and their log-probabilities, (B, A) and (B, 1)."""
        latent = _mlp(obs, params[:-4], self._latent_acts)
        # mu and log_std read the same latent: one matmul of their stacked weights
        heads = th.nn.functional.linear(latent, th.cat([params[-4], params[-2]]), th.cat([params[-3], params[-1]]))
        mean, log_std = heads.split([params[-4].shape[0], params[-2].shape[0]], dim=1)
        log_std = th.clamp(log_std, LOG_STD_MIN, LOG_STD_MAX)
        actions = th.tanh(mean + noise * log_std.exp())
        log_prob = (-0.5 * noise * noise - log_std - _LOG_SQRT_2PI).sum(dim=1, keepdim=True)
        log_prob = log_prob - th.log(1 - actions * actions + self._epsilon).sum(dim=1, keepdim=True)
        return actions, log_prob

    def _update(self, actor_params: list[th.Tensor], critic_params: list[list[th.Tensor]],
                target_params: list[list[th.Tensor]], log_alpha: th.Tensor, states: tuple, obs: th.Tensor,
                actions: th.Tensor, next_obs: th.Tensor, rewards: th.Tensor, dones: th.Tensor, discounts: th.Tensor,
                noise_pi: th.Tensor, noise_next: th.Tensor, target_entropy: float
                ) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        (a_avgs, a_sqs, a_step, a_lr, a_hyper), (c_avgs, c_sqs, c_step, c_lr, c_hyper), \
            (t_avgs, t_sqs, t_step, t_lr, t_hyper) = states
        actor_p = [p.detach() for p in actor_params]
        critic_p = [[p.detach() for p in ps] for ps in critic_params]
        size = len(critic_p[0])
        acts = self._critic_acts

        # ent_coef: the value before the temperature's step, as SB3 takes it for both losses
        ent_coef = log_alpha.detach().exp()
        with th.no_grad():  # 3. critic target
            next_actions, next_log_prob = self._actor(actor_p, next_obs, noise_next)
            next_input = th.cat([next_obs, next_actions], dim=1)
            next_q = _critics(next_input, [[p.detach() for p in ps] for ps in target_params], acts)
            next_q = th.min(next_q, dim=1, keepdim=True).values - ent_coef * next_log_prob
            target_q = rewards + (1 - dones) * discounts * next_q

        critic_input = th.cat([obs, actions], dim=1)

        def critic_loss_of(flat: list[th.Tensor]) -> th.Tensor:
            qs = _critics(critic_input, [flat[k:k + size] for k in range(0, len(flat), size)], acts)
            # SB3: 0.5 * sum_k mse(q_k, target)
            return 0.5 * ((qs - target_q) ** 2).mean(dim=0).sum()

        flat_critic = [p for ps in critic_p for p in ps]
        critic_grads, critic_loss = th.func.grad_and_value(critic_loss_of)(flat_critic)
        new_critic, c_avgs_new, c_sqs_new, c_step_new = _adam(flat_critic, critic_grads, c_avgs, c_sqs, c_step[0], c_lr,
                                                              *c_hyper)

        # 4. actor, through the critics after their step; its log_prob (step 1) also drives step 2, whose
        # result nothing else in this update reads, so it may come last
        def actor_loss_of(params: list[th.Tensor]) -> tuple[th.Tensor, th.Tensor]:
            actions_pi, log_prob = self._actor(params, obs, noise_pi)
            q_input = th.cat([obs, actions_pi], dim=1)
            qs = _critics(q_input, [new_critic[k:k + size] for k in range(0, len(new_critic), size)], acts)
            min_q = th.min(qs, dim=1, keepdim=True).values
            return (ent_coef * log_prob - min_q).mean(), log_prob.detach()

        actor_grads, (actor_loss, log_prob_pi) = th.func.grad_and_value(actor_loss_of, has_aux=True)(actor_p)
        new_actor, a_avgs_new, a_sqs_new, a_step_new = _adam(actor_p, actor_grads, a_avgs, a_sqs, a_step[0], a_lr,
                                                             *a_hyper)
        # 2. temperature: the gradient of -(log_alpha * (log_prob + target_entropy)).mean(), written out
        alpha_grad = -(log_prob_pi + target_entropy).mean().reshape(log_alpha.shape)
        ent_coef_loss = -(log_alpha.detach() * (log_prob_pi + target_entropy)).mean()
        (new_alpha,), (t_avg_new,), (t_sq_new,), t_step_new = _adam([log_alpha.detach()], [alpha_grad], t_avgs, t_sqs,
                                                                    t_step[0], t_lr, *t_hyper)

        with th.no_grad():  # write back into the model's tensors and its optimizers' states
            for dst, src in zip([*actor_params, *[p for ps in critic_params for p in ps], log_alpha],
                                [*new_actor, *new_critic, new_alpha]):
                dst.copy_(src)
            for dst, src in zip([*a_avgs, *a_sqs, *c_avgs, *c_sqs, *t_avgs, *t_sqs],
                                [*a_avgs_new, *a_sqs_new, *c_avgs_new, *c_sqs_new, t_avg_new, t_sq_new]):
                dst.copy_(src)
            # every parameter's step count (Adam keeps one each; all of an optimizer's step together)
            for steps, new_step in ((a_step, a_step_new), (c_step, c_step_new), (t_step, t_step_new)):
                for step in steps:
                    step.copy_(new_step)
        return ent_coef_loss, ent_coef, critic_loss.detach(), actor_loss.detach()



def batch_features(model: Any, replay_data: Any) -> tuple[th.Tensor, th.Tensor]:
    """The actor's (parameter-free) features of a batch's observations and next observations."""
    actor = model.actor
    with th.no_grad():
        return (actor.extract_features(replay_data.observations, actor.features_extractor),
                actor.extract_features(replay_data.next_observations, actor.features_extractor))


def train_compiled(model: Any, gradient_steps: int, batch_size: int) -> None:
    """``FastSAC.train`` with each gradient step run by the model's ``CompiledSACUpdate``."""
    update = getattr(model, "_compiled_update", None)
    if update is None or update.model is not model:
        update = model._compiled_update = CompiledSACUpdate(model)
    critic_params = list(model.critic.parameters())
    target_params = list(model.critic_target.parameters())
    foreach_polyak = "foreach_polyak" in model.speedups
    run_updates(model, update.step, gradient_steps, batch_size,
                lambda: model._polyak(critic_params, target_params, foreach_polyak))


def run_updates(model: Any, step: Callable, gradient_steps: int, batch_size: int, polyak: Callable[[], None]) -> None:
    """``FastSAC.train``'s loop around a one-step function ``step(replay_data, discounts)`` (the compiled or the
    fused update): learning rates, batches, the Polyak update every ``target_update_interval`` steps, the log."""
    model.policy.set_training_mode(True)
    model._update_learning_rate([model.actor.optimizer, model.critic.optimizer, model.ent_coef_optimizer])
    ent_coef_losses, ent_coefs, critic_losses, actor_losses = [], [], [], []
    for gradient_step in range(gradient_steps):
        replay_data = model._sample(batch_size)
        discounts = replay_data.discounts if replay_data.discounts is not None else model.gamma
        ent_coef_loss, ent_coef, critic_loss, actor_loss = step(replay_data, discounts)
        ent_coef_losses.append(ent_coef_loss)
        ent_coefs.append(ent_coef)
        critic_losses.append(critic_loss)
        actor_losses.append(actor_loss)
        if gradient_step % model.target_update_interval == 0:
            polyak()
    model._record_update(gradient_steps, ent_coefs, actor_losses, critic_losses, ent_coef_losses)
