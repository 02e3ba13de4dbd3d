"""What each exported dimension is: names, a continuous tool rotation, and no NaN passed on.

Layouts (``state_layout``) follow the envs' docstrings; a layout is chosen by the observation's
size and the episodes' action level:

- ToolPick-v0 (high level, 14-D; 17-D with the object's extent; ToolPickFlat-v0's 32-D adds hand q
  and q-dot): tool position (m), the tool's extrinsic xyz Euler angles (rad), z_bar, object and
  target positions (m), all in hand_base. Real trials (``real_trial``) and ``hingelab trial`` frames
  (``export_trial``) have the 14-D one.
- ToolShape-v0 (low level, 26-D): hand q (rad) and q-dot (rad/s) per joint, tool v_bar (m/s) and
  omega_bar (rad/s) in hand_base, z_bar; achieved goal z_bar, desired goal z_goal.

Any other size gets ``state_0 .. state_{D-1}``.

**Rotation**: Euler angles wrap at +-pi (a tool held upside down flips between +pi and -pi
from one frame to the next), which breaks mean/std and quantile normalization. The exported
state replaces them by the 6-D rotation (Zhou et al. 2019: the first two columns of the rotation
matrix), which is continuous and bounded in [-1, 1]; the env's own observation, Euler angles and
all, is kept beside it (``ENV_OBSERVATION``) so that the policy's exact input and the round trip
stay available.

**NaN**: an exported value is never NaN silently. ``fill_target`` applies the env's rule to a
real trial's missing target (5 cm above the object's position at the episode's first step, world
z; ``tasks.TARGET_HEIGHT``), with the hand's pose from the recorded arm joints through the scene's
kinematics (``sim.arm_kinematics``); what no rule defines is refused in one line naming the field
and the episode (``refuse_nan``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.episodes import schemas as S
from hingelab.episodes.errors import DatasetError
from hingelab.sim.arm_kinematics import default_kinematics
from hingelab.tasks import TARGET_HEIGHT

XYZ = ("x", "y", "z")
EULER = slice(3, 6)  # the tool's Euler angles in ToolPick-v0's observation
TARGET = slice(11, 14)  # the target in ToolPick-v0's observation
OBJECT = slice(8, 11)
ARM_JOINT_INFOS = tuple(f"arm_joint_{i}" for i in range(1, 7))  # a real import's step infos (rad)
ROT6D_NAMES = [f"tool_rot_c{c}_{a}" for c in (0, 1) for a in XYZ]  # columns 0 and 1 of R (hand_base <- tool)
HIGH_LEVEL_ACTION_NAMES = ["z_goal_0", "z_goal_1", "hand_vx", "hand_vy", "hand_vz"]
ENV_OBSERVATION = "env.observation"  # the env's own flat observation, where the exported state re-encodes it


def _xyz(prefix: str) -> list[str]:
    return [f"{prefix}_{a}" for a in XYZ]


@dataclass(frozen=True)
class StateLayout:
    """Names of the recorded observation's dimensions (per key) and whether its Euler angles are re-encoded."""

    names: dict[str, list[str]]  # "observation", "achieved_goal", "desired_goal" -> names, recorded order
    action: list[str]
    tool_pick: bool  # ToolPick-v0's layout: Euler angles at 3:6, the target at 11:14

    def state_names(self) -> list[str]:
        """``observation.state``'s names: the Euler angles replaced by the 6-D rotation."""
        names = self.names["observation"]
        return [*names[:EULER.start], *ROT6D_NAMES, *names[EULER.stop:]] if self.tool_pick else list(names)


def state_layout(obs_shapes: dict[str, tuple], action_dim: int, action_levels: list[str],
                 joint_names: list[str]) -> StateLayout:
    """The layout of an export's observations (``obs_shapes``: key -> per-step shape)."""
    joints = list(joint_names) if len(joint_names) == 9 else list(S.SVH_JOINT_NAMES)
    dim = obs_shapes["observation"][0] if len(obs_shapes["observation"]) == 1 else None
    tool_pick = ["tool_x", "tool_y", "tool_z", "tool_euler_x", "tool_euler_y", "tool_euler_z", "z_bar_0",
                 "z_bar_1", *_xyz("object"), *_xyz("target")]
    names = None
    if action_levels == ["high"] and dim in (14, 17, 32):
        names = {14: tool_pick, 17: tool_pick + _xyz("object_extent"),
                 32: tool_pick + joints + [f"{j}_vel" for j in joints]}[dim]
    elif action_levels == ["low"] and dim == 26:
        names = joints + [f"{j}_vel" for j in joints] + _xyz("tool_v") + _xyz("tool_omega") + ["z_bar_0", "z_bar_1"]
    layout = {"observation": names or [f"state_{i}" for i in range(int(np.prod(obs_shapes["observation"])))]}
    if "achieved_goal" in obs_shapes:
        layout["achieved_goal"] = ["z_bar_0", "z_bar_1"] if obs_shapes["achieved_goal"] == (2,) else None
        layout["desired_goal"] = ["z_goal_0", "z_goal_1"] if obs_shapes["desired_goal"] == (2,) else None
        for key in ("achieved_goal", "desired_goal"):
            layout[key] = layout[key] or [f"{key}_{i}" for i in range(int(np.prod(obs_shapes[key])))]
    if action_levels == ["high"] and action_dim == 5:
        action = list(HIGH_LEVEL_ACTION_NAMES)
    elif action_levels == ["low"] and action_dim == 9:
        action = [f"{j}_delta" for j in joints]
    else:
        action = [f"action_{i}" for i in range(action_dim)]
    return StateLayout(names=layout, action=action, tool_pick=names is not None and action_levels == ["high"])


def rotation_6d(euler_xyz: np.ndarray) -> np.ndarray:
    """(T, 3) extrinsic xyz Euler angles (rad) -> (T, 6): the first two columns of the rotation matrix."""
    matrix = Rotation.from_euler("xyz", np.asarray(euler_xyz, np.float64)).as_matrix()  # (T, 3, 3)
    return np.concatenate([matrix[:, :, 0], matrix[:, :, 1]], axis=1)


def encode_state(observation: np.ndarray, layout: StateLayout) -> np.ndarray:
    """``observation.state`` from the env's flat observation (T, D): Euler angles -> 6-D rotation (ToolPick)."""
    if not layout.tool_pick:
        return observation
    return np.concatenate([observation[:, :EULER.start], rotation_6d(observation[:, EULER]),
                           observation[:, EULER.stop:]], axis=1)


def fill_target(episode, observation: np.ndarray, infos: dict[str, np.ndarray]) -> tuple[np.ndarray, bool]:
    """ToolPick-v0's observation with a NaN target filled by the env's rule; (observation, filled).

    The target is 5 cm (world z) above the object's position at the first step; in hand_base at
    step k: ``R_k^T (target - p_k)``, with the hand's pose (R_k, p_k) from the step infos
    ``arm_joint_1..6`` through the scene's kinematics. A NaN target with no arm joints, or a NaN object
    position at the first step, is refused (one line naming the episode).
    """
    target = observation[:, TARGET]
    if not np.isnan(target).any():
        return observation, False
    arm = [infos.get(name) for name in ARM_JOINT_INFOS]
    if any(a is None for a in arm) or not np.isfinite(np.stack(arm, axis=1)).all():
        raise DatasetError(f"{episode.path}: observation target (state columns {TARGET.start}-{TARGET.stop - 1}) is "
                           "NaN and the episode has no arm joints (infos arm_joint_1..6) to place it; "
                           "re-import the bag with the arm's joint_states")
    if not np.isfinite(observation[0, OBJECT]).all():
        raise DatasetError(f"{episode.path}: observation target is NaN and so is the object's position at the first "
                           "step, which the target is 5 cm above; record the object's pose from the trial's start")
    rotation, position = default_kinematics().hand_poses(np.stack(arm, axis=1))
    object_world = rotation[0] @ observation[0, OBJECT] + position[0]
    target_world = object_world + np.array([0.0, 0.0, TARGET_HEIGHT])
    filled = observation.copy()
    filled[:, TARGET] = np.einsum("tji,tj->ti", rotation, target_world - position)  # R^T (target - p)
    return filled, True


def refuse_nan(episode, name: str, values: np.ndarray) -> None:
    """One ``DatasetError`` naming the field, the episode and the first frame, if ``values`` has a NaN."""
    values = np.asarray(values)
    if values.dtype.kind != "f":
        return
    bad = np.isnan(values.reshape(len(values), -1)).any(axis=1)
    if bad.any():
        raise DatasetError(f"{episode.path}: {name} is NaN in {int(bad.sum())} of {len(values)} frames (first: frame "
                           f"{int(np.flatnonzero(bad)[0])}) and no rule defines it; fix or filter out this episode")


__all__ = ["ENV_OBSERVATION", "HIGH_LEVEL_ACTION_NAMES", "ROT6D_NAMES", "StateLayout", "encode_state", "fill_target",
           "refuse_nan", "rotation_6d", "state_layout"]
