"""``hingelab/ToolPickFlat-v0``: the flat baseline, picking an object with one policy.

## Description
ToolPick-v0's task, scene and randomization (``hingelab.envs.tool_pick``) without the
hierarchy: there is no latent goal and no low level, one policy moves the 9 SVH finger
channels and the hand at once (the paper's non-hierarchical ablation). Reward, success,
attempts, episode end and failure reasons are ToolPick-v0's, by the same code
(``ToolPickFlatEnv`` subclasses ``ToolPickEnv`` and replaces only the finger command and
the observation). The hinge has no servo here: the fingers alone open and close the
tweezer against its spring, as in ToolShape-v0. There being no goal, ``info["z_goal"]`` (and
a recording's goal latent) holds the latent z_bar reached, as ToolPick-v0's heuristic steps do.

## Action Space
``Box(-1, 1, (12,))``:

| index | meaning | scale (value 1 =) |
| --- | --- | --- |
| 0-8 | relative joint-position change of the 9 SVH channels | 0.05 rad per 50 ms step (ToolShape-v0's) |
| 9-11 | linear velocity of the hand frame (hand_base axes) | 0.08 m/s (ToolPick-v0's ``max_speed``) |

The finger channels are in the driver's order (thumb flexion, thumb opposition, index
distal, index proximal, middle distal, middle proximal, ring, pinky, spread); target =
current position + change, clipped to the joint ranges. The velocity goes to the arm
through the damped Jacobian pseudoinverse. Values outside [-1, 1] are clipped; a non-finite
value or another shape is a ``ConfigError``.

## Observation Space
``Box(32,)``: ToolPick-v0's 14 (tool t_bar (3, m), Euler theta_bar (3, rad, xyz), z_bar (2),
object position (3, m, 2 mm noise), target position (3, m), in the hand frame, through the
episode's observation delay), then hand q (9, rad) and q-dot (9, rad/s) as ToolShape-v0 and
the low level see them (the episode's sensor delay, the same delay as the first 14).

## Rewards
ToolPick-v0's: ``c_h1 [success] + exp(-c_h2 ||tool - object||) + c_h3 exp(-c_h4 ||object -
target||) - c_h5 [a distance > 20 cm or a table collision]`` (``hingelab.envs.rewards``), the
terms in ``info["reward_terms"]``.

## Episode End
ToolPick-v0's: terminated on success (object within 1 cm of the target; ``success_verdict``
``"object_within_1cm"``) or when the tool leaves the hand (failure reason "tool_drop");
truncated after ``max_episode_steps`` (200) or on divergence ("divergence"); a failed grasp
starts attempt 2 (``info["attempt"]``, ``info["first_attempt_success"]``; a truncated episode
after a lost grasp fails as "drop", else "timeout").

## Arguments
ToolPick-v0's, but for ``low_level`` (there is none): ``object`` ("sphere"), ``size``
(0.02 m), ``mass`` (0.01 kg), ``randomize`` (True: object friction 1-5, finger friction, gains
60-150% of hand and arm servos, observation delays up to 150 ms), ``placement_half_width`` (0.05 m),
``max_episode_steps`` (200), ``encoder_path``, ``reward``, ``render_mode``,
``terminate_on_drop`` (True). ``command_privileged`` (the heuristic's path) is refused.

## Version History
v0: first version.
"""

from __future__ import annotations

import numpy as np

from hingelab.envs.tool_pick import MAX_SPEED, ToolPickEnv
from hingelab.errors import ConfigError
from hingelab.tasks import FLAT_FINGERS, TOOL_PICK_FLAT_ID, task_spaces

FINGER_SCALE = 0.05  # rad per step: ToolShape-v0's default action_scale (and PolicyLowLevel's)
N_FINGERS = FLAT_FINGERS


class NoLowLevel:
    """The flat env's stand-in for a low level: nothing turns goals into finger motion."""

    kind = "none"

    def reset(self) -> None:
        pass

    def act(self, sim, z_goal, low_obs=None) -> dict:
        raise ConfigError("ToolPickFlat-v0 has no low level: its action moves the fingers")


class ToolPickFlatEnv(ToolPickEnv):
    env_name = "ToolPickFlat-v0"

    def __init__(self, **kwargs):
        """ToolPick-v0's arguments (see the module docstring), without ``low_level``."""
        if "low_level" in kwargs:
            raise ConfigError("ToolPickFlat-v0 has no low level (its action moves the fingers); drop low_level")
        super().__init__(low_level="privileged", **kwargs)
        self.low_level = NoLowLevel()
        self.observation_space, self.action_space = task_spaces(TOOL_PICK_FLAT_ID, self.observe_extent)

    def command_privileged(self, arm_velocity_world, hinge_target, hand_targets) -> None:
        raise ConfigError("ToolPickFlat-v0 takes no privileged commands (the heuristic runs on ToolPick-v0)")

    def _finger_action(self, action: np.ndarray) -> tuple[dict, np.ndarray]:
        return {"hand_action": action[:N_FINGERS] * FINGER_SCALE}, action[N_FINGERS:] * MAX_SPEED

    def _observation(self) -> np.ndarray:
        q, qdot = self.sim.hand_observation()
        return np.concatenate([super()._observation(), q, qdot])

    def _info(self, terms: dict, success: bool) -> dict:
        self.z_goal = self.sample.z_smoothed[0].copy()  # no goal: the latent reached stands for it
        return super()._info(terms, success)
