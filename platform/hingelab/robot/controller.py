"""The hierarchical controller on robot readings: camera frame -> tool state -> high level -> low level -> commands.

Robot-agnostic: it reads only ``RobotReadings`` and returns the command for ``Robot.command``,
so the same object runs the stand-in and a real rig. Per control period:

1. the camera cloud pipeline turns the frame into the tool's 256-point cloud in hand_base, and
   ``ToolState`` into the tool's pose, velocities and latent (the envs' perception);
2. the high-level observation, laid out as ToolPick-v0's: the tool pose (position, Euler angles;
   smoothed, alpha 0.9), z_bar, the object's centre and the target (5 cm above the object's first
   estimate: the paper's goal) in hand_base, and the object's extent if the policy observes it;
3. the high-level policy's action: a latent goal (``Z_SCALE``) and the hand velocity (``MAX_SPEED``);
4. the low-level policy's observation (hand q and q-dot, v_bar, omega_bar, z_bar) and its finger
   changes (the hand adds them to its current positions).

A frame that gives no cloud returns ``flag`` instead of a command, and so does a step before the robot
has ever reported an object estimate (``flag`` ``no_object_estimate``: the target is 5 cm above the first
estimate, and there is nothing to reach for): the trial decides (it ends the trial as ``no_camera_cloud``
or ``no_object_estimate``). An estimate that later goes missing (the tool hides the object) is the robot's
to hold: the controller keeps the target and, without a centre, the target's point below it.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hingelab.envs.low_level import PolicyLowLevel
from hingelab.envs.tool_pick import TARGET_HEIGHT
from hingelab.errors import ConfigError
from hingelab.perception.camera_cloud import ToolCloudConfig, tool_cloud_from_frame
from hingelab.perception.encoder import load_encoder
from hingelab.perception.observed_tool_pose import ObservedToolPose, check_tool_position
from hingelab.perception.tool_state import ToolState
from hingelab.policies.baselines import ScriptedPolicy
from hingelab.policies.high_level import (
    check_context,
    load_high_level_checkpoint,
    observes_extent,
    trained_tool_position,
)
from hingelab.robot.interface import RobotReadings
from hingelab.tasks import MAX_SPEED, Z_SCALE

NO_OBJECT_ESTIMATE = "no_object_estimate"  # the flag (and the failure reason) of a trial without an object estimate


@dataclass
class Step:
    """One control period's decision and what it was made from (for the recording)."""

    hand_velocity: np.ndarray | None  # (3,) m/s, hand_base; None when flagged
    hand_changes: np.ndarray | None  # (9,) rad, from the hand's current positions
    action: np.ndarray | None  # (5,) the high level's action in [-1, 1]
    z_goal: np.ndarray | None
    cloud: np.ndarray | None  # (256, 3) hand_base
    sample: object | None  # ToolStateSample
    observation: np.ndarray | None
    object_hand: np.ndarray | None
    target_hand: np.ndarray | None
    flag: str | None = None


class CheckpointHighLevel:
    """A high-level checkpoint (``hingelab train high``: SAC or the phase clone), checked against the low level it
    learned over."""

    def __init__(self, path: str | Path, low_level: str | None = None):
        self.label = str(path)
        self.model = load_high_level_checkpoint(path)
        recorded = getattr(self.model, "hingelab_provenance", None) or {}
        self.low_level = low_level or recorded.get("low_level", "policy")
        if self.low_level == "privileged":
            raise ConfigError("a trial needs a low-level policy (the privileged low level commands the hinge, "
                              "which a real tweezer does not have); give --low-level policy or a checkpoint")
        check_context(self.model, path, self.low_level)
        self.observe_extent = observes_extent(self.model)
        self.tool_position = trained_tool_position(self.model)

    def reset(self, seed: int) -> None:
        self.state = None  # a policy with memory (the phase clone) starts its episode afresh

    def act(self, observation: np.ndarray) -> np.ndarray:
        action, self.state = self.model.predict(observation[None], state=self.state, deterministic=True)
        return np.asarray(action, float)[0]


class ScriptedStandInHighLevel:
    """The scripted high level (``eval high --baseline scripted``), which reads the stand-in's simulator:
    what a trial on the stand-in runs when there is no high-level checkpoint. Not for a real rig."""

    observe_extent = False
    label = "scripted"

    def __init__(self, robot, low_level: str | None = None):
        if not hasattr(robot, "env"):
            raise ConfigError("the scripted high level reads the simulator: it runs on --robot sim only; give a "
                              "high-level checkpoint (hingelab train high) for a real rig")
        self.robot, self.policy = robot, ScriptedPolicy()
        self.low_level = low_level or "policy"

    def reset(self, seed: int) -> None:
        self.policy.reset(self.robot.env, seed)

    def act(self, observation: np.ndarray) -> np.ndarray:
        return self.policy.act(self.robot.env, observation)


class HierarchicalController:
    """A high level (``CheckpointHighLevel`` or ``ScriptedStandInHighLevel``) over a low-level policy,
    perceiving through the camera pipeline."""

    def __init__(self, high_level, encoder=None, cloud_config: ToolCloudConfig = ToolCloudConfig(),
                 tool_position: str = "observed"):
        # the forms of ToolPick-v0's tool pose (hingelab.perception.observed_tool_pose): "anchored" and "relative"
        # drop the hand-eye error's constant, "nominal" does without tracking
        self.tool_position = check_tool_position(tool_position)
        self.encoder = encoder or load_encoder()
        self.high_level = high_level
        self.observe_extent = high_level.observe_extent
        low = PolicyLowLevel(high_level.low_level, encoder=self.encoder)
        self.low_model, self.low_action_scale = low.model, low.action_scale
        self.tool_state = ToolState(encoder=self.encoder, n_tools=1)
        self.cloud_config = cloud_config
        self.rng = np.random.default_rng()
        self._tool_pose = ObservedToolPose(self.tool_position, self.tool_state.prior)
        self.target_world = np.zeros(3)
        self._fresh = True

    def reset(self, readings: RobotReadings, seed: int) -> None:
        """A new trial: forget the tool's history; the target is 5 cm above the object's first estimate (None
        until the robot reports one)."""
        self.tool_state.reset()
        self.high_level.reset(seed)
        self.rng = np.random.default_rng([seed, 37])
        self.target_world = None
        if readings.object_centre is not None:
            self.target_world = np.asarray(readings.object_centre, float) + [0.0, 0.0, TARGET_HEIGHT]
        self._fresh = True

    def act(self, readings: RobotReadings) -> Step:
        if self.target_world is None:
            if readings.object_centre is None:
                return Step(None, None, None, None, None, None, None, None, None, flag=NO_OBJECT_ESTIMATE)
            self.target_world = np.asarray(readings.object_centre, float) + [0.0, 0.0, TARGET_HEIGHT]
        cloud = tool_cloud_from_frame(readings.frame, self.cloud_config, self.rng)
        if cloud.points is None:
            return Step(None, None, None, None, None, None, None, None, None, flag=cloud.flag)
        sample = self.tool_state.update(cloud.points[None], n_distinct=cloud.n_distinct)
        pose = (sample.rotation[0], sample.position[0], sample.euler_xyz[0])
        tool_pose = self._tool_pose.reset(*pose) if self._fresh else self._tool_pose.update(*pose)
        self._fresh = False
        z_bar = sample.z_smoothed[0]
        centre = (readings.object_centre if readings.object_centre is not None
                  else self.target_world - [0, 0, TARGET_HEIGHT])
        object_hand, target_hand = readings.to_hand(centre), readings.to_hand(self.target_world)
        parts = [tool_pose, z_bar, object_hand, target_hand]
        if self.observe_extent:
            parts.append(np.zeros(3) if readings.object_extent is None else np.asarray(readings.object_extent, float))
        observation = np.concatenate(parts)
        action = np.clip(self.high_level.act(observation), -1.0, 1.0)
        z_goal, hand_velocity = action[:2] * Z_SCALE, action[2:] * MAX_SPEED
        low_obs = np.concatenate([readings.hand_position, readings.hand_velocity, sample.velocity_smoothed[0],
                                  sample.angular_velocity_smoothed[0], z_bar])
        low_action, _ = self.low_model.predict({"observation": low_obs[None], "achieved_goal": z_bar[None],
                                                "desired_goal": z_goal[None]}, deterministic=True)
        changes = np.clip(np.asarray(low_action, float)[0], -1, 1) * self.low_action_scale
        return Step(hand_velocity, changes, action, z_goal, cloud.points, sample, observation, object_hand,
                    target_hand)
