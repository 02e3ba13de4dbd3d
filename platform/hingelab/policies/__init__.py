"""Policies: what acts, and how any of them is loaded.

``Policy`` (``predict(observation, state, episode_start) -> (action, state)``, as stable-baselines3's
policies) and ``EpisodePolicy`` (what rollouts drive) are in ``policy``; ``load_policy`` finds a
checkpoint's format or a baseline's name in the registry of ``loading``. The formats and baselines
that come with hingelab register here, on import: stable-baselines3 SAC zips loaded without unpickling
(``sb3_zip``), checked against ToolShape-v0 (``low_level``) or ToolPick-v0 (``high_level``), the
goal-region experts manifest (``goal_experts``), the phase clone (``phase_clone``), a residual over it
(``residual``) and the baselines (``baselines``). This package sits below the envs: ToolPick-v0 gets its
low level through it.
"""

from hingelab.policies import baselines, goal_experts, high_level  # noqa: F401  (they register their formats)
from hingelab.policies.loading import (
                                       BASELINES,
                                       FORMATS,
                                       baseline_names,
                                       load_policy,
                                       policy_format,
                                       register_baseline,
                                       register_policy_format,
)
from hingelab.policies.policy import EpisodePolicy, ModelPolicy, Policy, as_episode_policy

__all__ = ["Policy", "EpisodePolicy", "ModelPolicy", "as_episode_policy", "load_policy", "policy_format",
           "register_policy_format", "register_baseline", "baseline_names", "FORMATS", "BASELINES"]
