"""The rig's depth camera seeing the object: depth, the object's and the tool's pixels, and the truth.

``ObjectDepthRenderer`` renders the ``rig_depth`` camera (``hingelab.sim.rig_camera``) as
``DepthRenderer`` does, and from the same segmentation render also marks the object's geoms, as the
tool mask marks the tweezer's. The camera is fixed in the world and the object rests on the
platform, so its frame is posed in the **world** frame (``CameraFrame.camera_rotation`` and
``camera_position``: optical frame -> world), not in ``hand_base`` as the tool's frames are; the
platform's crop box (``platform_crop``) is in the world too.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from hingelab.camera import CameraFrame
from hingelab.sim import names
from hingelab.sim.depth_render import DepthRenderer
from hingelab.sim.objects import ObjectSpec
from hingelab.sim.rig_camera import camera_pose_world


@dataclass
class ObjectFrame:
    """One rendered frame with the object's pixels: ``frame`` posed in the world, masks (H, W) bool."""

    frame: CameraFrame
    object_mask: np.ndarray  # the object's pixels as the simulator's segmentation gives them (no errors)


class ObjectDepthRenderer(DepthRenderer):
    """``render(data) -> ObjectFrame``: noise-free depth, the tool's and the object's masks, the world pose."""

    def __init__(self, model: mujoco.MjModel, intrinsics):
        super().__init__(model, intrinsics)
        self._object_geoms = np.flatnonzero(model.geom_bodyid == model.body(names.OBJECT_BODY).id)

    def render(self, data: mujoco.MjData, stamp_s: float = 0.0) -> ObjectFrame:
        depth, geoms = self.depth_and_geoms(data)
        rot_w, pos_w = camera_pose_world(self.model, data)
        frame = CameraFrame(depth=depth, intrinsics=self.intrinsics, camera_rotation=rot_w, camera_position=pos_w,
                            tool_mask=np.isin(geoms, self._tool_geoms), stamp_s=stamp_s)
        return ObjectFrame(frame, np.isin(geoms, self._object_geoms))


def platform_crop(model: mujoco.MjModel, min_height: float = 0.002,
                  max_height: float = 0.06) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """The box (low, high), world frame, m, over the platform's top: its footprint, from ``min_height`` above
    its surface (which drops the platform's own pixels) to ``max_height`` (above the largest object)."""
    g = model.geom("platform").id
    centre, half = model.geom_pos[g], model.geom_size[g]
    top = float(centre[2] + half[2])
    low = (float(centre[0] - half[0]), float(centre[1] - half[1]), top + min_height)
    high = (float(centre[0] + half[0]), float(centre[1] + half[1]), top + max_height)
    return low, high


def true_object_centre(model: mujoco.MjModel, data: mujoco.MjData, obj: ObjectSpec) -> np.ndarray:
    """The object's centre (world, m): the middle of its resting height, as ``ToolPickEnv`` observes it."""
    body = model.body(names.OBJECT_BODY).id
    up = data.xmat[body].reshape(3, 3)[:, 2]
    return data.xpos[body] + up * obj.centre_height


def true_object_extent(model: mujoco.MjModel, data: mujoco.MjData) -> np.ndarray:
    """(3,) the object's bounding box along the world axes, m, from its geoms' boxes (``geom_aabb``) as posed now:
    what ``ToolPickEnv.observed_object_extent`` observes for a fixed object (a family's drawn mesh pieces aside)."""
    geoms = np.flatnonzero(model.geom_bodyid == model.body(names.OBJECT_BODY).id)
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = model.geom_aabb[geoms, None, :3] + signs * model.geom_aabb[geoms, None, 3:]  # (geoms, 8, 3)
    rotations = data.geom_xmat[geoms].reshape(-1, 3, 3)
    world = (data.geom_xpos[geoms, None] + np.einsum("gij,gkj->gki", rotations, corners)).reshape(-1, 3)
    return world.max(axis=0) - world.min(axis=0)
