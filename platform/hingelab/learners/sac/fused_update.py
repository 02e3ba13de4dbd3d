"""One SAC gradient step written out by hand: ``FastSAC(update="fused")``.

``torch.compile`` leaves the matmuls as they were and the profile says where the rest goes
(``analysis/bench/history/sac_updates.md``): a fresh 256 KB activation buffer per op, which is
slow to write here, autograd's bookkeeping, and about 300 small ops. This update keeps the
algorithm and removes those three:

- **the backward pass by hand**: the gradients of the three losses are written out for
  MLPs of Linear + ReLU/Tanh layers (each a matmul or an elementwise product), so no autograd
  graph is built and nothing is computed that is thrown away (the critic's weight gradients in
  the actor loss, the actor's input gradient);
- **every buffer allocated once**: activations, their gradients and the parameter gradients
  live in tensors made on the first step and rewritten with ``out=`` and in-place ops;
- **the critics as one stacked network**: each layer's weights of all critics are one
  ``(n_critics, out, in)`` tensor that the modules' own ``weight``/``bias`` are views of, so a
  layer of every critic is one batched matmul (``bmm``), the Polyak update is a few ``_foreach``
  ops on the stacks, and the ensemble costs no Python loop per critic.

The model stays a plain SB3 model: its parameters are still the modules' parameters (views of
the stacks), Adam is still the model's own fused ``torch.optim.Adam`` stepping on ``.grad``
(views of gradient stacks), so saving, loading (``load_state_dict`` copies in place), resuming
and switching to the eager update keep working, and the file loads as plain ``SAC``.

Same algorithm as ``stable_baselines3.SAC.train`` up to floating-point order, in its order: the
actor's squashed Gaussian on the observations; the temperature's loss and Adam step; the critic
target from the next observations (``ent_coef`` from before the temperature's step); the critic
loss ``0.5 * sum_k mse(q_k, target)`` and its Adam step; the actor loss through the critics after
their step, and its Adam step; the Polyak update. The Gaussian noise is drawn with the eager
update's calls in its order, so a seed gives the same batches and noise.

Supported: what ``CompiledSACUpdate.check`` accepts (a learned temperature, MLP actor and
critics of Linear/ReLU/Tanh, parameter-free feature extractors, Adam without weight decay).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import torch as th
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN
from torch import nn

from hingelab.learners.sac.compiled_update import CompiledSACUpdate, batch_features, run_updates

_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))


def _layout(sequential: nn.Sequential) -> tuple[list[nn.Linear], list[str | None]]:
    """The Linear layers of an MLP and the activation after each ("relu", "tanh" or None)."""
    linears: list[nn.Linear] = []
    activations: list[str | None] = []
    for layer in sequential:
        if isinstance(layer, nn.Linear):
            linears.append(layer)
            activations.append(None)
        elif isinstance(layer, (nn.ReLU, nn.Tanh)) and linears and activations[-1] is None:
            activations[-1] = "relu" if isinstance(layer, nn.ReLU) else "tanh"
        else:
            raise ValueError(f"the fused SAC update supports MLPs of Linear, ReLU and Tanh, not {layer}")
    return linears, activations


def _activate_(x: th.Tensor, activation: str | None) -> None:
    if activation == "relu":
        x.clamp_(min=0)
    elif activation == "tanh":
        x.tanh_()


def _activation_backward_(grad: th.Tensor, out: th.Tensor, activation: str | None, scratch: th.Tensor) -> None:
    """``grad`` *= d activation / d input, from the activation's output ``out`` (in place)."""
    if activation == "relu":
        # autograd's own ReLU backward (0 where the output is <= 0), written into grad: one pass, where a
        # comparison into a bool buffer and a multiply take ten times as long here
        th.ops.aten.threshold_backward.grad_input(grad, out, 0, grad_input=grad)
    elif activation == "tanh":
        th.mul(out, out, out=scratch)
        scratch.neg_().add_(1)
        grad.mul_(scratch)


class _Stack:
    """Linear layers as stacked tensors that the layers' own parameters (and their ``.grad``) are views
    of: layer ``i`` is ``weights[i]``, (n, out, in), and ``biases[i]``, (n, out).

    ``layers[i]`` lists the Linears of layer ``i``: one per critic (stacked along n) or, with
    ``concat[i]``, Linears that read the same input, joined along ``out`` (the actor's mean and
    log_std heads), n = 1.
    """

    def __init__(self, layers: Sequence[Sequence[nn.Linear]], activations: Sequence[str | None],
                 concat: Sequence[bool]):
        self.activations = list(activations)
        self.layers = [list(linears) for linears in layers]
        self.weights: list[th.Tensor] = []
        self.biases: list[th.Tensor] = []
        self.weight_grads: list[th.Tensor] = []
        self.bias_grads: list[th.Tensor] = []
        self._views: list[tuple[nn.Linear, int, slice]] = []  # (linear, index in the stack, rows)
        self._layer_of: list[int] = []
        for i, (linears, joined) in enumerate(zip(self.layers, concat)):
            if joined:
                weights = th.cat([linear.weight.detach() for linear in linears]).unsqueeze(0)
                biases = th.cat([linear.bias.detach() for linear in linears]).unsqueeze(0)
                starts = [0]
                for linear in linears:
                    starts.append(starts[-1] + linear.out_features)
                places = [(0, slice(start, end)) for start, end in zip(starts, starts[1:])]
            else:
                weights = th.stack([linear.weight.detach() for linear in linears])
                biases = th.stack([linear.bias.detach() for linear in linears])
                places = [(k, slice(None)) for k in range(len(linears))]
            for linear, (k, rows) in zip(linears, places):
                linear.weight.data = weights[k, rows]
                linear.bias.data = biases[k, rows]
                self._views.append((linear, k, rows))
                self._layer_of.append(i)
            self.weights.append(weights)
            self.biases.append(biases)
            self.weight_grads.append(th.zeros_like(weights))
            self.bias_grads.append(th.zeros_like(biases))

    @classmethod
    def of_critics(cls, networks: Sequence[nn.Sequential]) -> _Stack:
        layouts = [_layout(net) for net in networks]
        linears, activations = layouts[0]
        return cls([[lins[i] for lins, _ in layouts] for i in range(len(linears))], activations,
                   [False] * len(linears))

    @classmethod
    def of_actor(cls, actor: Any) -> _Stack:
        linears, activations = _layout(actor.latent_pi)
        return cls([*[[linear] for linear in linears], [actor.mu, actor.log_std]], [*activations, None],
                   [False] * len(linears) + [True])

    def intact(self) -> bool:
        """Whether every layer's parameters are still views of the stacks (an outside ``.data = ...``
        assignment would cut them loose)."""
        return all(linear.weight.data_ptr() == self.weights[i][k, rows].data_ptr()
                   and linear.bias.data_ptr() == self.biases[i][k, rows].data_ptr()
                   for (linear, k, rows), i in zip(self._views, self._layer_of))

    def attach_grads(self) -> None:
        """Point each parameter's ``.grad`` at its slice of the gradient stacks (``zero_grad`` unsets them)."""
        for (linear, k, rows), i in zip(self._views, self._layer_of):
            weight_grad, bias_grad = self.weight_grads[i][k, rows], self.bias_grads[i][k, rows]
            if linear.weight.grad is None or linear.weight.grad.data_ptr() != weight_grad.data_ptr():
                linear.weight.grad = weight_grad
            if linear.bias.grad is None or linear.bias.grad.data_ptr() != bias_grad.data_ptr():
                linear.bias.grad = bias_grad

    def parameters(self) -> list[th.Tensor]:
        return [*self.weights, *self.biases]


class _Buffers:
    """Every tensor one update writes, made once for a batch size."""

    def __init__(self, batch: int, obs_dim: int, action_dim: int, actor: _Stack, critic: _Stack, dtype: th.dtype):
        n = critic.weights[0].shape[0]
        critic_widths = [w.shape[1] for w in critic.weights]
        actor_widths = [w.shape[1] for w in actor.weights]
        new = lambda *shape: th.empty(shape, dtype=dtype)  # noqa: E731
        # the actor runs on the observations and the next observations as one batch of 2B rows
        self.actor_in = new(2 * batch, obs_dim)
        self.actor_hidden = [new(2 * batch, width) for width in actor_widths]  # last: [mean | log_std]
        self.actor_grads = [new(batch, width) for width in actor_widths]
        self.actor_scratch = [new(batch, width) for width in actor_widths]
        # the critics' inputs: (obs, actions), (next_obs, next_actions), (obs, actions_pi)
        self.critic_in = new(batch, obs_dim + action_dim)
        self.target_in = new(batch, obs_dim + action_dim)
        self.pi_in = new(batch, obs_dim + action_dim)
        self.critic_hidden = [new(n, batch, width) for width in critic_widths]
        self.critic_grads = [new(n, batch, width) for width in critic_widths]
        self.critic_scratch = [new(n, batch, width) for width in critic_widths]
        self.input_grads = new(n, batch, action_dim)
        self.action_grad = new(batch, action_dim)
        self.noise = new(2, batch, action_dim)


class _AdamStep:
    """``optimizer.step()`` for a fused ``torch.optim.Adam``: the same kernel (``torch._fused_adam_``) on the
    same tensors, without ``Optimizer.step``'s per-call bookkeeping (hooks, grouping by device, a scalar
    add per parameter's step count), which costs more than the kernel here. The step counts become views
    of one tensor, so one add counts them all (Adam's own ``step()`` still counts each view once).
    Anything else (not fused, several groups, a first step that creates the states) goes through
    ``optimizer.step()``; a new state (``load_state_dict``) is picked up on the next call."""

    def __init__(self, optimizer: th.optim.Optimizer):
        self.optimizer = optimizer
        self._state: Any = None

    def __call__(self) -> None:
        optimizer = self.optimizer
        groups = optimizer.param_groups
        if len(groups) != 1 or not groups[0].get("fused"):
            optimizer.step()
            return
        group = groups[0]
        params = group["params"]
        if self._state is not optimizer.state or self._params is not params or not self._steps_are_views():
            if any(p not in optimizer.state for p in params):
                optimizer.step()  # Adam's first step makes the states
                return
            self._bind(params)
        self._counts.add_(1)
        beta1, beta2 = group["betas"]
        th._fused_adam_(params, [p.grad for p in params], self._avgs, self._sqs, [], self._steps, amsgrad=False,
                        lr=float(group["lr"]), beta1=float(beta1), beta2=float(beta2),
                        weight_decay=float(group["weight_decay"]), eps=float(group["eps"]), maximize=False)

    def _bind(self, params: list[th.Tensor]) -> None:
        states = [self.optimizer.state[p] for p in params]
        self._counts = th.stack([state["step"].detach().to(th.float32).reshape(()) for state in states])
        for i, state in enumerate(states):
            state["step"] = self._counts[i]
        self._steps = [state["step"] for state in states]
        self._avgs = [state["exp_avg"] for state in states]
        self._sqs = [state["exp_avg_sq"] for state in states]
        self._state, self._params, self._states = self.optimizer.state, params, states

    def _steps_are_views(self) -> bool:
        return all(state["step"] is step for state, step in zip(self._states, self._steps))


class FusedSACUpdate:
    """The gradient step of one ``FastSAC`` model, by hand, into buffers made once.

    ``step(replay_data, discounts)`` runs one update in place on the model's parameters and its
    optimizers and returns the detached (ent_coef_loss, ent_coef, critic_loss, actor_loss).
    """

    def __init__(self, model: Any):
        problem = self.check(model)
        if problem:
            raise ValueError(f"the fused SAC update does not support this model: {problem}")
        self.model = model
        actor = model.actor
        self.actor = _Stack.of_actor(actor)
        self.critic = _Stack.of_critics(model.critic.q_networks)
        self.target = _Stack.of_critics(model.critic_target.q_networks)
        self.action_dim = actor.mu.out_features
        self._epsilon = float(actor.action_dist.epsilon)
        self._buffers: _Buffers | None = None
        self._adam = {name: _AdamStep(optimizer) for name, optimizer in (
            ("actor", actor.optimizer), ("critic", model.critic.optimizer), ("ent_coef", model.ent_coef_optimizer))}

    @staticmethod
    def check(model: Any) -> str | None:
        """Why the fused update cannot run ``model`` (None: it can)."""
        problem = CompiledSACUpdate.check(model)
        if problem is None and any(not isinstance(q[-1], nn.Linear) or q[-1].out_features != 1
                                   for q in model.critic.q_networks):
            problem = "critics that do not end in a Linear layer with one output"
        return problem

    def intact(self) -> bool:
        return self.actor.intact() and self.critic.intact() and self.target.intact()

    # --- pieces ---------------------------------------------------------------------------------

    def _actor_forward(self, buffers: _Buffers) -> None:
        """The actor's layers on the 2B rows of ``actor_in``; the last holds [mean | log_std]."""
        x = buffers.actor_in
        for i, activation in enumerate(self.actor.activations):
            out = buffers.actor_hidden[i]
            th.addmm(self.actor.biases[i][0], x, self.actor.weights[i][0].t(), out=out)
            _activate_(out, activation)
            x = out

    def _squash(self, heads: th.Tensor, noise: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Actions, log-probabilities (B, 1) and std from [mean | log_std]."""
        a = self.action_dim
        mean, raw_log_std = heads[:, :a], heads[:, a:]
        log_std = raw_log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        std = log_std.exp()
        actions = th.tanh(mean + noise * std)
        log_prob = (-0.5 * noise * noise - log_std - _LOG_SQRT_2PI).sum(dim=1, keepdim=True)
        log_prob -= th.log(1 - actions * actions + self._epsilon).sum(dim=1, keepdim=True)
        return actions, log_prob, std

    def _critic_forward(self, stack: _Stack, x: th.Tensor, buffers: _Buffers) -> th.Tensor:
        """Every critic of ``stack`` on ``x`` (B, in): (n, B, 1) values; the hidden layers stay in buffers."""
        n = stack.weights[0].shape[0]
        h = None
        last = len(stack.activations) - 1
        for i, activation in enumerate(stack.activations):
            weights_t = stack.weights[i].transpose(1, 2)
            bias = stack.biases[i].unsqueeze(1)
            if i == last:
                return th.baddbmm(bias, h, weights_t)
            out = buffers.critic_hidden[i]
            if h is None:  # the first layer reads the same input for every critic
                th.baddbmm(bias, x.expand(n, *x.shape), weights_t, out=out)
            else:
                th.baddbmm(bias, h, weights_t, out=out)
            _activate_(out, activation)
            h = out
        raise AssertionError("unreachable: a critic has at least one layer")

    def _critic_backward(self, stack: _Stack, x: th.Tensor, grad_q: th.Tensor, buffers: _Buffers,
                         weight_grads: bool) -> th.Tensor | None:
        """Backpropagate ``grad_q`` (n, B, 1) through the critics' last forward on ``x``.

        ``weight_grads``: write the parameter gradients into the gradient stacks and return None;
        else return the gradient with respect to the actions (the input's last columns), (B, A).
        """
        n = stack.weights[0].shape[0]
        last = len(stack.activations) - 1
        grad = grad_q
        for i in range(last, -1, -1):
            layer_in = buffers.critic_hidden[i - 1] if i > 0 else None
            if weight_grads:
                inputs = layer_in if layer_in is not None else x.expand(n, *x.shape)
                th.bmm(grad.transpose(1, 2), inputs, out=stack.weight_grads[i])
                th.sum(grad, dim=1, out=stack.bias_grads[i])
            if i == 0:
                break
            below = buffers.critic_grads[i - 1]
            th.bmm(grad, stack.weights[i], out=below)
            _activation_backward_(below, buffers.critic_hidden[i - 1], stack.activations[i - 1],
                                  buffers.critic_scratch[i - 1])
            grad = below
        if weight_grads:
            return None
        a = self.action_dim
        th.bmm(grad, stack.weights[0][:, :, -a:], out=buffers.input_grads)
        return th.sum(buffers.input_grads, dim=0, out=buffers.action_grad)

    def _actor_backward(self, grad_heads: th.Tensor, buffers: _Buffers) -> None:
        """Backpropagate ``grad_heads`` (B, 2A) through the actor's forward on the first B rows."""
        batch = grad_heads.shape[0]
        grad = grad_heads
        for i in range(len(self.actor.activations) - 1, -1, -1):
            layer_in = buffers.actor_hidden[i - 1][:batch] if i > 0 else buffers.actor_in[:batch]
            th.mm(grad.t(), layer_in, out=self.actor.weight_grads[i][0])
            th.sum(grad, dim=0, out=self.actor.bias_grads[i][0])
            if i == 0:
                break
            below = buffers.actor_grads[i - 1]
            th.mm(grad, self.actor.weights[i][0], out=below)
            _activation_backward_(below, buffers.actor_hidden[i - 1][:batch], self.actor.activations[i - 1],
                                  buffers.actor_scratch[i - 1])
            grad = below

    # --- one step -------------------------------------------------------------------------------

    def step(self, replay_data: Any, discounts: Any) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        """One update on ``replay_data``; returns (ent_coef_loss, ent_coef, critic_loss, actor_loss), detached."""
        obs, next_obs = batch_features(self.model, replay_data)
        with th.no_grad():
            return self._step(obs, next_obs, replay_data, discounts)

    def _step(self, obs: th.Tensor, next_obs: th.Tensor, replay_data: Any,
              discounts: Any) -> tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]:
        model = self.model
        batch, obs_dim = obs.shape
        a = self.action_dim
        buffers = self._buffers
        if buffers is None or buffers.actor_in.shape != (2 * batch, obs_dim) or buffers.actor_in.dtype != obs.dtype:
            buffers = self._buffers = _Buffers(batch, obs_dim, a, self.actor, self.critic, obs.dtype)
        self.actor.attach_grads()
        self.critic.attach_grads()
        buffers.noise[0].normal_()  # the eager update's two draws, in its order
        buffers.noise[1].normal_()
        discounts = th.as_tensor(discounts, dtype=obs.dtype)

        # 1. the actor on obs and next_obs at once
        buffers.actor_in[:batch].copy_(obs)
        buffers.actor_in[batch:].copy_(next_obs)
        self._actor_forward(buffers)
        heads = buffers.actor_hidden[-1]
        actions_pi, log_prob, std = self._squash(heads[:batch], buffers.noise[0])
        next_actions, next_log_prob, _ = self._squash(heads[batch:], buffers.noise[1])

        # 2. temperature: the gradient of -(log_alpha * (log_prob + target_entropy)).mean(), written out
        log_alpha = model.log_ent_coef
        ent_coef = log_alpha.detach().exp()
        entropy_gap = (log_prob + model.target_entropy).mean()
        ent_coef_loss = -(log_alpha.detach() * entropy_gap).squeeze()
        log_alpha.grad = (-entropy_gap).reshape(log_alpha.shape)
        self._adam["ent_coef"]()

        # 3. the critic target from the next observations
        buffers.target_in[:, :obs_dim].copy_(next_obs)
        buffers.target_in[:, obs_dim:].copy_(next_actions)
        next_q = self._critic_forward(self.target, buffers.target_in, buffers).min(dim=0).values
        target_q = replay_data.rewards + (1 - replay_data.dones) * discounts * (next_q - ent_coef * next_log_prob)

        # the critic loss 0.5 * sum_k mean_b (q_kb - target_b)^2 and its gradient (q - target) / B
        buffers.critic_in[:, :obs_dim].copy_(obs)
        buffers.critic_in[:, obs_dim:].copy_(replay_data.actions)
        errors = self._critic_forward(self.critic, buffers.critic_in, buffers) - target_q
        critic_loss = 0.5 * (errors * errors).mean(dim=1).sum()
        self._critic_backward(self.critic, buffers.critic_in, errors.div_(batch), buffers, weight_grads=True)
        self._adam["critic"]()

        # 4. the actor loss mean(ent_coef * log_prob - min_k q_k(obs, actions_pi)) through the stepped critics
        buffers.pi_in[:, :obs_dim].copy_(obs)
        buffers.pi_in[:, obs_dim:].copy_(actions_pi)
        q_pi = self._critic_forward(self.critic, buffers.pi_in, buffers)
        min_q, argmin = q_pi.min(dim=0)
        actor_loss = (ent_coef * log_prob - min_q).mean()
        grad_q = th.zeros_like(q_pi).scatter_(0, argmin.unsqueeze(0), -1.0 / batch)
        grad_actions = self._critic_backward(self.critic, buffers.pi_in, grad_q, buffers, weight_grads=False)
        # through actions = tanh(u), u = mean + noise * std, log_prob's -sum(log std) - sum(log(1 - a^2 + eps))
        alpha = ent_coef / batch
        one_minus = 1 - actions_pi * actions_pi
        grad_u = (grad_actions + alpha * 2 * actions_pi / (one_minus + self._epsilon)) * one_minus
        grad_heads = buffers.actor_grads[-1]
        grad_heads[:, :a].copy_(grad_u)
        in_range = (heads[:batch, a:] >= LOG_STD_MIN) & (heads[:batch, a:] <= LOG_STD_MAX)
        th.mul(grad_u * buffers.noise[0] * std - alpha, in_range, out=grad_heads[:, a:])
        self._actor_backward(grad_heads, buffers)
        self._adam["actor"]()
        return ent_coef_loss, ent_coef, critic_loss, actor_loss

    def polyak(self, tau: float) -> None:
        """The target critics' Polyak update on the stacks (SB3's mul_ then add with alpha)."""
        targets = self.target.parameters()
        th._foreach_mul_(targets, 1 - tau)
        th._foreach_add_(targets, self.critic.parameters(), alpha=tau)


def train_fused(model: Any, gradient_steps: int, batch_size: int) -> None:
    """``FastSAC.train`` with each gradient step run by the model's ``FusedSACUpdate``."""
    update = getattr(model, "_fused_update", None)
    if update is None or update.model is not model or not update.intact():
        update = model._fused_update = FusedSACUpdate(model)

    def polyak() -> None:
        with th.no_grad():
            update.polyak(model.tau)

    run_updates(model, update.step, gradient_steps, batch_size, polyak)
