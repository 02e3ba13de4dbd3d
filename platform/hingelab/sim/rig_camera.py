"""The rig's depth camera: an Azure Kinect DK at the rig's viewpoint, added to a scene.

Intrinsics: ``hingelab.camera.AZURE_KINECT_NFOV_UNBINNED`` by default (its docstring gives
the mode and the source of its numbers).

Pose (``RIG_VIEW``): over the platform, in front of the hand and to its right, 0.6 m from
the tool, looking down at it by 17 degrees: eye (0.90, -0.42, 0.50), looking at
(0.50, -0.01, 0.32), world frame of ``tool_pick`` with the arm at home. From there the
tweezer's two legs are seen side by side below the fingers (the fingers hide the rest;
straight from the front they hide more). In ``tool_shape`` (the hand fixed in the world,
no arm) the camera sits at the same place relative to the hand.

MuJoCo renders the camera with these intrinsics (``<camera resolution focalpixel
principalpixel sensorsize>``); its frame looks along -z with +y up. ``CameraModel.optical``
gives the OpenCV/ROS optical frame (x right, y down, z forward) that the cloud pipeline uses.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hingelab.camera import AZURE_KINECT_NFOV_UNBINNED, DepthIntrinsics
from hingelab.errors import ConfigError

CAMERA_NAME = "rig_depth"
PIXEL_PITCH_M = 3.5e-6  # the depth sensor's pixel (MuJoCo needs a sensor size to take pixel intrinsics)
# hand_base in tool_pick's world frame with the arm at home (the grasp keyframe); a test checks it
PICK_HAND_HOME = np.array([0.378, 0.032, 0.369])
SHAPE_HAND_POSE = np.array([0.0, 0.0, 0.5])  # hand_base in tool_shape's world frame (fixed mount)


@dataclass(frozen=True)
class CameraView:
    """Where the camera is: eye and look-at point (world frame of tool_pick, arm at home), m."""

    eye: tuple[float, float, float] = (0.90, -0.42, 0.50)
    look_at: tuple[float, float, float] = (0.50, -0.01, 0.32)

    def mujoco_rotation(self) -> np.ndarray:
        """R (3, 3): MuJoCo camera frame (x right, y up, looking along -z) -> world; the horizon level."""
        forward = np.asarray(self.look_at, float) - np.asarray(self.eye, float)
        forward /= np.linalg.norm(forward)
        right = np.cross(forward, [0.0, 0.0, 1.0])
        if np.linalg.norm(right) < 1e-6:
            raise ConfigError(f"camera view {self} looks straight up or down; tilt it")
        right /= np.linalg.norm(right)
        up = np.cross(right, forward)
        return np.stack([right, up, -forward], axis=1)


RIG_VIEW = CameraView()
MJ_TO_OPTICAL = np.diag([1.0, -1.0, -1.0])  # MuJoCo camera axes -> optical (x right, y down, z forward)


def camera_world_position(view: CameraView, scene: str) -> np.ndarray:
    """The eye in ``scene``'s world frame: tool_pick's rig, or the same place relative to tool_shape's hand."""
    eye = np.asarray(view.eye, float)
    if scene == "tool_pick":
        return eye
    if scene == "tool_shape":
        return eye - PICK_HAND_HOME + SHAPE_HAND_POSE  # both hands have the same orientation in the world
    raise ConfigError(f"no rig camera placement for scene {scene!r}; use tool_pick or tool_shape")


def add_rig_camera(spec: mujoco.MjSpec, scene: str, intrinsics: DepthIntrinsics = AZURE_KINECT_NFOV_UNBINNED,
                   view: CameraView = RIG_VIEW) -> None:
    """Add the depth camera ``rig_depth`` to ``spec``'s world body, and an offscreen buffer its size."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, view.mujoco_rotation().ravel())
    camera = spec.worldbody.add_camera(name=CAMERA_NAME, pos=camera_world_position(view, scene), quat=quat)
    camera.resolution = [intrinsics.width, intrinsics.height]
    camera.sensor_size = [intrinsics.width * PIXEL_PITCH_M, intrinsics.height * PIXEL_PITCH_M]
    camera.focal_pixel = [intrinsics.fx, intrinsics.fy]
    # MuJoCo's principal point is the offset from the image centre, in pixels
    camera.principal_pixel = [intrinsics.cx - intrinsics.width / 2, intrinsics.cy - intrinsics.height / 2]
    spec.visual.global_.offwidth = max(spec.visual.global_.offwidth, intrinsics.width)
    spec.visual.global_.offheight = max(spec.visual.global_.offheight, intrinsics.height)


def camera_pose_world(model: mujoco.MjModel, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)): the optical frame -> world, as simulated now."""
    cam = model.camera(CAMERA_NAME).id
    rot = data.cam_xmat[cam].reshape(3, 3) @ MJ_TO_OPTICAL
    return rot, data.cam_xpos[cam].copy()
