"""The low level inside ToolPick-v0: it turns the high level's latent goal into finger motion.

Two kinds, one interface (``reset``, ``act(z_goal) -> None`` acting on the sim):

* ``PrivilegedLowLevel``: drives the hinge to the opening that z_goal calibrates to, with
  the privileged hinge servo, the fingers following the grasp synergy so the tool stays
  held. ToolPick-v0 works with it before any low-level policy is trained.
* ``PolicyLowLevel``: a trained low-level SAC checkpoint (``hingelab train low``) observing
  the hand and tool as in ToolShape-v0 and moving the 9 finger channels, or goal-region experts
  (``hingelab compose low``: the goal's opening picks the checkpoint). The shipped one,
  ``assets/checkpoints/low_level_experts.json``, is the default (``low_level="policy"`` in ToolPick-v0).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.errors import ConfigError
from hingelab.policies.goal_experts import GoalRegionExperts
from hingelab.policies.loading import load_policy
from hingelab.policies.low_level import SHIPPED_LOW_LEVEL, recorded_action_scale, resolve_low_level
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy

FINGER_SQUEEZE = 0.03  # rad the fingers aim past the commanded opening (keeps leg b pressed)


class PrivilegedLowLevel:
    """z_goal -> opening (calibration) -> hinge servo target, fingers from the synergy."""

    kind = "privileged"

    def __init__(self, calibration, synergy: FingerSynergy | None = None):
        self.calibration = calibration
        self.synergy = synergy or FingerSynergy.load()

    def reset(self) -> None:
        pass

    def opening_for(self, z_goal: np.ndarray) -> float:
        low, high = self.synergy.theta_range
        return float(np.clip(self.calibration.opening_rad(np.asarray(z_goal, float)), max(low, 0.0), high))

    def act(self, sim: SimCore, z_goal: np.ndarray, low_obs: np.ndarray | None = None) -> dict:
        """Set this step's hand and hinge commands; returns them for ``sim.step``."""
        opening = self.opening_for(z_goal)
        sim.set_hand_targets(self.synergy.targets(opening - FINGER_SQUEEZE))
        return {"hinge_target": opening}


class PolicyLowLevel:
    """A trained low-level policy: observation (26,) + z_goal (2,) -> 9 finger changes."""

    kind = "policy"

    def __init__(self, checkpoint: str | Path = SHIPPED_LOW_LEVEL, encoder=None):
        """``checkpoint``: a SAC zip, a run folder or one of its checkpoints/step_* folders (the
        model.zip inside), or a goal-region experts manifest (.json, ``hingelab compose low``).
        ``encoder``: the ToolEncoder the env perceives with (default: the shipped one). The
        action scale (rad per step of a full action) is the one the checkpoint was trained with."""
        path = resolve_low_level(checkpoint)
        if path == "privileged":
            raise ConfigError("PolicyLowLevel needs a checkpoint; the privileged low level is PrivilegedLowLevel")
        self.path = path
        self.model = load_policy(path, level="low", encoder=encoder)
        if not isinstance(getattr(self.model, "observation_space", None), gym.spaces.Dict):
            raise ConfigError(f"{path} is not a low-level policy (ToolShape-v0's goal-conditioned observation); "
                              "give a checkpoint from `hingelab train low` or `hingelab compose low`")
        if isinstance(self.model, GoalRegionExperts):
            scales = {recorded_action_scale(m) for m in self.model.experts}
            if len(scales) != 1:
                raise ConfigError(f"{path}: its experts were trained with different action scales {sorted(scales)}")
            self.action_scale = scales.pop()
        else:
            self.action_scale = recorded_action_scale(self.model)

    def reset(self) -> None:
        pass

    def act(self, sim: SimCore, z_goal: np.ndarray, low_obs: np.ndarray | None = None) -> dict:
        obs = {"observation": low_obs[None], "achieved_goal": low_obs[None, -2:],
               "desired_goal": np.asarray(z_goal, float)[None]}
        action, _ = self.model.predict(obs, deterministic=True)
        return {"hand_action": np.clip(action[0], -1, 1) * self.action_scale}
