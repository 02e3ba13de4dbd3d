"""The object's position and extent from a rig bag's camera frames (``import-ros2 --object-from-cloud``).

A rig without motion capture or an object detector logs no object pose, but its depth camera sees the
object. Each camera frame a step takes goes through the stand-in's object chain
(``hingelab.perception.object_estimate``), in the **world**: the arm's base frame, where the pick scene
has the platform (``hingelab.sim.object_render.platform_crop``). The camera is placed there by the
bag's TF (the camera in ``hand_base``, at the frame's stamp) and the arm's kinematics of the logged
arm joints (``hand_base`` in the world, at the same stamp: ``hingelab.sim.arm_kinematics``), the same
kinematics that ``train high`` uses to put an imported object back into the world, so the platform
is where training takes it to be. Then:

- **segmentation**: with a mask topic (``object_mask``: the rig's segmentation of the depth image,
  mono8, stamped as its image), the masked pixels, as the stand-in's simulated segmentation
  (``object_cloud``); without one (or for a PointCloud2 of the scene), by geometry alone
  (``object_cloud_from_scene``): the scene's points above the platform's top, inside its footprint,
  minus those within 5 mm of the frame's tool cloud;
- **the estimator** (``estimate_from_cloud``): ``centroid`` (the paper's), ``ray_corrected`` (the
  default: the best per-frame estimator by its 95th percentile in analysis/objects), ``primitive_fit``;
  the extent is the visible points' bounding box along the world's axes.

``ObjectTrack`` turns the frames' estimates into the steps' (``StepObject``): a step whose frame gives
none (flagged: no object points, hidden by the tool, no arm joints, ...) carries the last estimate, as
the env does with a dropout; the estimate is kept in the world and put into the step's ``hand_base``
with the hand's pose at the step, so a carried one stays where the object was while the hand moves.
Before the first estimate of a trial the position is NaN (never a made-up one): the import reports it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hingelab.camera import CameraFrame
from hingelab.errors import ConfigError
from hingelab.perception.camera_cloud import depth_to_points, transform
from hingelab.perception.object_estimate import (
    ESTIMATORS,
    MODEL_ESTIMATORS,
    ObjectCloudConfig,
    estimate_from_cloud,
    object_cloud,
    object_cloud_from_scene,
)
from hingelab.sim.arm_kinematics import ArmKinematics, default_kinematics
from hingelab.sim.object_render import platform_crop

DEFAULT_ESTIMATOR = "ray_corrected"
CLOUD_ESTIMATORS = tuple(name for name in ESTIMATORS if name not in MODEL_ESTIMATORS)  # a bag carries no object model
NO_ARM_JOINTS = "no_arm_joints"  # the frame's flag when no arm joint state places the hand in the world
NO_CAMERA_POSE = "no_camera_pose"  # ... when TF cannot place the camera in hand_base
NO_OBJECT_MASK = "no_object_mask"  # ... when the bag has a mask topic but no mask of this frame


def check_estimator(name: str) -> str:
    if name in MODEL_ESTIMATORS:
        raise ConfigError(f"--object-from-cloud {name!r}: fits the object's model, which a bag does not carry; "
                          f"choose one of {', '.join(CLOUD_ESTIMATORS)}")
    if name not in ESTIMATORS:
        raise ConfigError(f"--object-from-cloud {name!r}: not an object estimator; choose one of "
                          f"{', '.join(CLOUD_ESTIMATORS)} (default {DEFAULT_ESTIMATOR}; a bag's path right after the "
                          "flag is read as its estimator: put the flag after the bags, or name the estimator)")
    return name


@dataclass
class FrameObject:
    """One camera frame's object: ``estimate`` (3,) and ``extent`` (3,) m and ``points`` (N, 3) m, world; or
    None with ``flag`` saying why. ``stamp``: the frame's, ns."""

    stamp: int
    estimate: np.ndarray | None = None
    extent: np.ndarray | None = None
    points: np.ndarray | None = None
    flag: str | None = None
    segmentation: str = ""  # "mask" or "scene"


@dataclass
class StepObject:
    """What a step records (``EpisodeWriter.write_object_estimate``), in the step's ``hand_base``: ``position``
    (3,) m the estimate in use (NaN before the first), ``extent`` (3,) m (zeros before it), ``points`` (N, 3)
    this frame's visible points (None when flagged), ``fresh``, ``flag``, ``stamp`` of the frame that gave
    the estimate in use (None before the first)."""

    position: np.ndarray
    extent: np.ndarray
    points: np.ndarray | None
    n_points: int
    fresh: bool
    flag: str
    stamp: int | None


class ObjectFromCloud:
    """``frame(...) -> FrameObject`` per camera frame; ``hand_in_world(arm_q)`` for the steps (module docstring)."""

    def __init__(self, estimator: str = DEFAULT_ESTIMATOR, kinematics: ArmKinematics | None = None):
        self.estimator = check_estimator(estimator)
        self.kinematics = kinematics or default_kinematics()
        low, high = platform_crop(self.kinematics.model)
        self.config = ObjectCloudConfig(crop_low=low, crop_high=high)

    def hand_in_world(self, arm_q) -> tuple[np.ndarray, np.ndarray] | None:
        """(R (3, 3), p (3,)): hand_base in the world at the arm joints ``arm_q`` (6,) rad; None without them."""
        if arm_q is None or not np.isfinite(arm_q).all():
            return None
        rot, pos = self.kinematics.hand_poses(np.asarray(arm_q, float)[None])
        return rot[0], pos[0]

    def frame(self, stamp: int, camera_in_hand, arm_q, *, scene_points=None, depth=None, intrinsics=None,
              mask=None, tool_points_hand=None) -> FrameObject:
        """The object in one frame. ``camera_in_hand`` (R, p): the optical frame in hand_base at ``stamp`` (None:
        TF had none); ``arm_q`` (6,) rad at ``stamp`` (None: no arm joints yet). The frame is ``scene_points``
        (N, 3) m in the optical frame, or ``depth`` (H, W) m with its ``intrinsics`` (and ``mask`` (H, W) bool,
        the rig's segmentation, if the bag has one). ``tool_points_hand`` (M, 3): the frame's tool cloud, whose
        neighbourhood the segmentation without a mask leaves out."""
        if camera_in_hand is None:
            return FrameObject(stamp, flag=NO_CAMERA_POSE)
        hand = self.hand_in_world(arm_q)
        if hand is None:
            return FrameObject(stamp, flag=NO_ARM_JOINTS)
        (hand_rot, hand_pos), (cam_rot, cam_pos) = hand, camera_in_hand
        rot, pos = hand_rot @ cam_rot, hand_rot @ cam_pos + hand_pos  # the optical frame in the world
        if mask is not None:
            frame = CameraFrame(depth, intrinsics, rot, pos, stamp_s=stamp / 1e9)
            cloud, segmentation = object_cloud(frame, mask, self.config), "mask"
        else:
            points = depth_to_points(depth, intrinsics) if scene_points is None else scene_points
            tool = None if tool_points_hand is None else transform(np.asarray(tool_points_hand, float), hand_rot,
                                                                  hand_pos)
            cloud, segmentation = object_cloud_from_scene(transform(points, rot, pos), self.config, tool), "scene"
        result = estimate_from_cloud(cloud, self.estimator, pos)
        return FrameObject(stamp, result.estimate, result.extent, cloud.points, result.flag, segmentation)

    @staticmethod
    def missing_mask(stamp: int) -> FrameObject:
        return FrameObject(stamp, flag=NO_OBJECT_MASK, segmentation="mask")


class ObjectTrack:
    """One trial's steps: ``reset()``, then ``step(frame, hand)`` per step (module docstring)."""

    def __init__(self):
        self.reset()

    def reset(self) -> None:
        self.estimate: np.ndarray | None = None  # world
        self.extent = np.zeros(3)
        self.stamp: int | None = None
        self.flags: dict[str, int] = {}
        self.steps = self.fresh_steps = 0
        self.before_first = 0  # steps before the first estimate
        self.first_flag: str | None = None  # the first step's flag, when it had no estimate

    def step(self, frame: FrameObject | None, hand: tuple[np.ndarray, np.ndarray] | None) -> StepObject:
        """``frame``: the step's camera frame's object (None: the frame gave no result); ``hand`` (R, p): hand_base
        in the world at the step (None: no arm joints, and the position is NaN)."""
        flag = "no_frame" if frame is None else frame.flag
        fresh = frame is not None and frame.estimate is not None
        if fresh:
            self.estimate, self.extent, self.stamp = frame.estimate, frame.extent, frame.stamp
        else:
            self.flags[flag] = self.flags.get(flag, 0) + 1
        self.steps += 1
        self.fresh_steps += int(fresh)
        if self.estimate is None:
            self.before_first += 1
            self.first_flag = self.first_flag or flag
        position, points = np.full(3, np.nan), None
        if hand is not None:
            rot, pos = hand
            if self.estimate is not None:
                position = rot.T @ (self.estimate - pos)
            if fresh:
                points = ((frame.points - pos) @ rot).astype(np.float32)
        return StepObject(position, self.extent.copy(), points, 0 if not fresh else len(frame.points), fresh,
                          flag or "", self.stamp)


__all__ = ["DEFAULT_ESTIMATOR", "FrameObject", "ObjectFromCloud", "ObjectTrack", "StepObject", "check_estimator"]
