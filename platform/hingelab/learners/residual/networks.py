"""The residual learner's networks, as a stable-baselines3 ``SACPolicy``:

* ``BoundedActor``: SB3's squashed-Gaussian actor whose mean layer starts at zero (the residual is 0: the
  policy at step 0 is its base) and whose log-std is capped (and optionally floored) per action dimension,
  so the executed
  exploration noise, ``scale * std`` before the tanh compresses it further, stays under the bound each
  dimension tolerates (``hingelab diagnose noise``).
* ``EnsembleCritic``: ``n_critics`` Q-networks with LayerNorm after every hidden layer (RLPD, Ball et
  al. 2023: LayerNorm keeps the critic from extrapolating wildly on actions the data never shows),
  evaluated as one batched network (weights ``(E, in, out)``, one ``baddbmm`` per layer, not a Python loop
  over members). Each Q takes the *executed* action, ``clip(base + scale * residual, -1, 1)``, rebuilt
  from the base's action inside the input, so demonstrations (whose actions the residual may not reach)
  and the policy's own transitions are valued on one scale.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from stable_baselines3.common.policies import BaseModel, ContinuousCritic
from stable_baselines3.sac.policies import Actor, SACPolicy
from torch import nn

from hingelab.policies.residual import EnsembleLinear, ResidualInputs, compose, ensemble_q_net, ensemble_q_values


class BoundedActor(Actor):
    """SB3's SAC actor with a zero-initialized mean layer and a per-dimension cap on its log-std."""

    def __init__(self, *args: Any, log_std_max=None, log_std_min=None, **kwargs: Any):
        super().__init__(*args, **kwargs)
        cap = th.as_tensor(np.asarray(log_std_max, np.float32))
        self.register_buffer("log_std_max", cap)
        # the floor is a plain attribute, not a buffer: checkpoints of runs without one keep loading exactly
        self.log_std_min = None if log_std_min is None else th.as_tensor(np.asarray(log_std_min, np.float32))
        with th.no_grad():
            self.mu.weight.zero_()
            self.mu.bias.zero_()
            self.log_std.weight.zero_()  # explore at the bound from the start (the temperature may lower it)
            self.log_std.bias.copy_(cap)

    def get_action_dist_params(self, obs):
        mean, log_std, kwargs = super().get_action_dist_params(obs)
        log_std = th.minimum(log_std, self.log_std_max)
        if self.log_std_min is not None:
            log_std = th.maximum(log_std, self.log_std_min)
        return mean, log_std, kwargs


class EnsembleCritic(ContinuousCritic):
    """Q(x, clip(base + scale * residual)) for ``n_critics`` members at once (module doc)."""

    def __init__(self, observation_space, action_space, net_arch, features_extractor, features_dim: int,
                 activation_fn=nn.ReLU, normalize_images: bool = True, n_critics: int = 2,
                 share_features_extractor: bool = False, scale=None, layer_norm: bool = True):
        BaseModel.__init__(self, observation_space, action_space, features_extractor=features_extractor,
                           normalize_images=normalize_images)
        self.share_features_extractor = share_features_extractor
        self.n_critics = int(n_critics)
        self.register_buffer("scale", th.as_tensor(np.asarray(scale, np.float32)))
        if activation_fn is not nn.ReLU:
            raise ValueError("the residual learner's critics are ReLU networks (a policy that chooses by Q rebuilds "
                             "them as hingelab.policies.residual.ensemble_q_net)")
        action_dim = int(np.prod(action_space.shape))
        self.net_arch, self.layer_norm = [int(n) for n in net_arch], bool(layer_norm)
        self.q_net = ensemble_q_net(self.n_critics, features_dim + action_dim, tuple(self.net_arch), layer_norm)
        self.q_networks = []  # SB3's per-member list; the members live in q_net

    def q_values(self, obs: th.Tensor, residual: th.Tensor, members: th.Tensor | None = None) -> th.Tensor:
        """(n_critics, batch, 1), or (len(members), batch, 1): only the members at those indices."""
        with th.set_grad_enabled(not self.share_features_extractor):
            features = self.extract_features(obs, self.features_extractor)
        executed = compose(ResidualInputs.base_action(obs), residual, self.scale)
        return ensemble_q_values(self.q_net, features, executed, self.n_critics, members)

    def policy_record(self) -> dict:
        """What ``ResidualPolicy.save`` keeps of the critics for a policy that chooses by Q."""
        return {"state": {k: v.detach().clone() for k, v in self.q_net.state_dict().items()},
                "members": self.n_critics, "hidden": self.net_arch, "layer_norm": self.layer_norm}

    def forward(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, ...]:
        return tuple(self.q_values(obs, actions).unbind(0))

    def q1_forward(self, obs: th.Tensor, actions: th.Tensor) -> th.Tensor:
        return self.q_values(obs, actions)[0]


class ResidualSACPolicy(SACPolicy):
    """SB3's SAC policy with ``BoundedActor`` and ``EnsembleCritic`` (module doc)."""

    def __init__(self, *args: Any, residual_scale=None, log_std_max=None, log_std_min=None,
                 critic_layer_norm: bool = True, **kwargs: Any):
        self.residual_scale = [float(s) for s in residual_scale]
        self.log_std_max = [float(v) for v in log_std_max]
        self.log_std_min = None if log_std_min is None else [float(v) for v in log_std_min]
        self.critic_layer_norm = bool(critic_layer_norm)
        super().__init__(*args, **kwargs)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "residual_scale": self.residual_scale,
                "log_std_max": self.log_std_max, "critic_layer_norm": self.critic_layer_norm,
                **({"log_std_min": self.log_std_min} if self.log_std_min is not None else {})}

    def make_actor(self, features_extractor=None) -> BoundedActor:
        actor_kwargs = self._update_features_extractor(self.actor_kwargs, features_extractor)
        return BoundedActor(**actor_kwargs, log_std_max=self.log_std_max, log_std_min=self.log_std_min).to(self.device)

    def make_critic(self, features_extractor=None) -> EnsembleCritic:
        critic_kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        return EnsembleCritic(**critic_kwargs, scale=self.residual_scale,
                              layer_norm=self.critic_layer_norm).to(self.device)


def actor_state_for_policy(actor: Actor) -> dict[str, th.Tensor]:
    """The deterministic part of an SB3 actor (``latent_pi`` then ``mu``) under ``policies.residual.actor_mlp``'s
    names (its Linear layers at 0, 2, ... and the mean layer last)."""
    linears = [m for m in actor.latent_pi if isinstance(m, nn.Linear)] + [actor.mu]
    state = {}
    for i, layer in enumerate(linears):
        state[f"{2 * i}.weight"] = layer.weight.detach().clone()
        state[f"{2 * i}.bias"] = layer.bias.detach().clone()
    return state


__all__ = ["BoundedActor", "EnsembleCritic", "EnsembleLinear", "ResidualSACPolicy", "actor_state_for_policy"]
# EnsembleLinear lives in hingelab.policies.residual (a policy that chooses by Q rebuilds the critics without SB3)
