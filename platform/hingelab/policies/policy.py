"""What a policy is to the platform.

``Policy``: a trained policy, the interface stable-baselines3's policies (and its recurrent ones) have:
``predict(observation, state, episode_start, deterministic) -> (action, state)``. ``state`` is the
policy's memory (None for a Markov policy; the phase clone's phase and steps), given back each step;
``episode_start`` marks the rows whose episode starts now (None: read ``state is None`` as the start).

``EpisodePolicy``: what a rollout drives, ``reset(env, seed)`` at each episode's start and
``act(env, obs) -> action`` each step. The privileged baselines (``hingelab.policies.baselines``) are
episode policies: they read the simulator through the env they act in. ``as_episode_policy`` wraps a
``Policy`` as one (deterministic actions, its memory kept between steps and dropped at each reset).
"""

from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class Policy(Protocol):
    def predict(self, observation, state: Any = None, episode_start: np.ndarray | None = None,
                deterministic: bool = True) -> tuple[np.ndarray, Any]: ...


@runtime_checkable
class EpisodePolicy(Protocol):
    def reset(self, env, seed: int) -> None: ...

    def act(self, env, obs) -> np.ndarray: ...


class ModelPolicy:
    """A ``Policy`` driven as an ``EpisodePolicy``: deterministic actions; a policy with memory gets its
    state back each step and a fresh one each episode, as SB3's recurrent policies do."""

    def __init__(self, model: Policy):
        self.model = model
        self.state = None

    def reset(self, env, seed: int) -> None:
        self.state = None  # None: the episode's start (SAC ignores it, the phase clone starts in "open")

    def act(self, env, obs) -> np.ndarray:
        action, self.state = self.model.predict(obs, state=self.state, deterministic=True)
        return np.asarray(action, np.float32)


def as_episode_policy(policy) -> EpisodePolicy:
    """``policy`` itself if it is an episode policy, else it wrapped in ``ModelPolicy``."""
    return policy if isinstance(policy, EpisodePolicy) else ModelPolicy(policy)


__all__ = ["Policy", "EpisodePolicy", "ModelPolicy", "as_episode_policy"]
