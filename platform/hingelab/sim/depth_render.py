"""Rendering the rig's depth camera offscreen: depth in metres and the tool's segmentation mask.

MuJoCo renders through OpenGL; which library provides the context is chosen by the
``MUJOCO_GL`` environment variable, read once per process when the first renderer is made:
``egl`` (headless: a GPU's EGL or Mesa's software EGL; what the tests use and the default
here when ``MUJOCO_GL`` is unset on Linux without a display: ``import hingelab`` sets it then,
before anything imports mujoco, which reads it once), ``osmesa`` (Mesa's software
renderer, where installed) or ``glfw`` (a window system, needs a display). A machine with
none of them gets one ``ConfigError`` naming ``MUJOCO_GL``.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np

from hingelab.camera import CameraFrame, DepthIntrinsics
from hingelab.errors import ConfigError
from hingelab.sim import names
from hingelab.sim.rig_camera import CAMERA_NAME, MJ_TO_OPTICAL, camera_pose_world

GL_HINT = ("set MUJOCO_GL to a backend this machine has: egl (headless, GPU or Mesa's libEGL), "
           "osmesa (Mesa's software renderer) or glfw (needs a display)")


def choose_gl_backend() -> str:
    """The GL backend in use: ``MUJOCO_GL`` (``import hingelab`` sets egl when it is unset on a Linux
    machine without a display; mujoco's own default is glfw)."""
    return os.environ.get("MUJOCO_GL", "glfw")


def make_renderer(model: mujoco.MjModel, height: int, width: int) -> mujoco.Renderer:
    """A ``mujoco.Renderer``, or one ``ConfigError`` naming ``MUJOCO_GL`` when no GL context can be made."""
    backend = choose_gl_backend()
    try:
        return mujoco.Renderer(model, height, width)
    except Exception as exc:  # FatalError, RuntimeError or AttributeError, by backend: all mean no context
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"no OpenGL context for offscreen rendering with MUJOCO_GL={backend} ({first}); "
                          f"{GL_HINT}") from exc


class DepthRenderer:
    """``render(data) -> CameraFrame``: the ``rig_depth`` camera's depth and tool mask, noise-free.

    Depth beyond the camera's range (the far plane, the sky) reads 0, as a real camera's
    missing returns do. The tool mask marks the pixels of the tweezer's geoms.
    """

    def __init__(self, model: mujoco.MjModel, intrinsics: DepthIntrinsics):
        if mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, CAMERA_NAME) < 0:
            raise ConfigError(f"the model has no {CAMERA_NAME!r} camera; build the sim with camera=intrinsics")
        self.model = model
        self.intrinsics = intrinsics
        self._renderer = make_renderer(model, intrinsics.height, intrinsics.width)
        tool_bodies = [model.body(names.TOOL_BODY_A).id, model.body(names.TOOL_BODY_B).id]
        self._tool_geoms = np.flatnonzero(np.isin(model.geom_bodyid, tool_bodies))
        self._hand_base = model.body(names.HAND_BASE_BODY).id

    def depth_and_geoms(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        """The depth image (0 out of range) and each pixel's geom id (-1: no geom), one render of each."""
        mujoco.mj_camlight(self.model, data)  # the sim steps with mj_kinematics, which leaves cameras as they were
        return self._depth_and_geoms(data)

    def depth_and_geoms_at(self, data: mujoco.MjData, rotation: np.ndarray, position: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray]:
        """``depth_and_geoms`` with the camera put at another pose (optical frame -> world): what the model
        looks like from where a miscalibrated rig believes its camera is. The camera's pose in ``data`` is
        restored after."""
        camera = self.model.camera(CAMERA_NAME).id
        mujoco.mj_camlight(self.model, data)
        saved = data.cam_xpos[camera].copy(), data.cam_xmat[camera].copy()
        try:
            data.cam_xpos[camera] = position
            data.cam_xmat[camera] = (np.asarray(rotation) @ MJ_TO_OPTICAL).reshape(-1)
            return self._depth_and_geoms(data)  # update_scene reads the camera's pose from data as it is
        finally:
            data.cam_xpos[camera], data.cam_xmat[camera] = saved

    def _depth_and_geoms(self, data: mujoco.MjData) -> tuple[np.ndarray, np.ndarray]:
        r = self._renderer
        r.enable_depth_rendering()
        r.update_scene(data, camera=CAMERA_NAME)
        depth = r.render().astype(np.float32, copy=True)
        r.disable_depth_rendering()
        r.enable_segmentation_rendering()
        r.update_scene(data, camera=CAMERA_NAME)
        seg = r.render()
        r.disable_segmentation_rendering()
        k = self.intrinsics
        depth[(depth < k.min_range_m) | (depth > k.max_range_m)] = 0.0
        geoms = np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1)
        return depth, geoms

    def render(self, data: mujoco.MjData, stamp_s: float = 0.0) -> CameraFrame:
        return self.frame_from(data, *self.depth_and_geoms(data), stamp_s=stamp_s)

    def frame_from(self, data: mujoco.MjData, depth: np.ndarray, geoms: np.ndarray,
                   stamp_s: float = 0.0) -> CameraFrame:
        """The frame of one ``depth_and_geoms`` render, posed in hand_base, with the tool's mask (a caller that
        also needs the geom ids, for the object's pixels, renders once and calls this)."""
        k = self.intrinsics
        mask = np.isin(geoms, self._tool_geoms)
        rot_w, pos_w = camera_pose_world(self.model, data)
        hand_rot = data.xmat[self._hand_base].reshape(3, 3)
        hand_pos = data.xpos[self._hand_base]
        return CameraFrame(depth=depth, intrinsics=k, camera_rotation=hand_rot.T @ rot_w,
                           camera_position=hand_rot.T @ (pos_w - hand_pos), tool_mask=mask, stamp_s=stamp_s)

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
