"""The arm's forward kinematics and the scene's surfaces, from the MuJoCo model of the pick scene.

A real rig logs the Zu 7's six joint angles, not where its hand is. ``ArmKinematics`` gives the
pose of ``hand_base`` in the world (= the arm's base frame, as in the sim) for recorded joint
angles with MuJoCo's own kinematics (``mj_kinematics``) on ``assets/scenes/tool_pick.xml``: the
same Zu 7 chain the simulator moves, so a pose is the one the sim would have at those angles
(no hand-written copy of the DH parameters). Only the arm's joints are set; the tool and the
object are free bodies and do not move the hand.

``surface_top_z(xy)``: the height (world z, m) of the surface under a point: the 20 cm platform's
top within its footprint, the table's top elsewhere (both boxes of the scene, read from the model).
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from hingelab.errors import ConfigError
from hingelab.sim import names
from hingelab.sim.scene import load_scene


class ArmKinematics:
    """Hand poses in the world from arm joint angles (``hand_poses``) and the surfaces' heights."""

    def __init__(self, model: mujoco.MjModel | None = None):
        if model is None:
            model = load_scene("tool_pick")
        self.model = model
        self.data = mujoco.MjData(model)
        self.qpos_adr = np.array([model.jnt_qposadr[model.joint(j).id] for j in names.ARM_JOINTS])
        self.hand_body = model.body(names.HAND_BASE_BODY).id
        key = model.key(names.GRASP_KEYFRAME).id
        self.data.qpos[:] = model.key_qpos[key]  # the other joints where the scene starts them
        jnt = [model.joint(j).id for j in names.ARM_JOINTS]
        self.joint_range = model.jnt_range[jnt].copy()  # (6, 2) rad
        self.surfaces = []  # (centre xy, half sizes xy, top z) of the table and the platform, highest first
        for geom in names.TABLE_GEOMS:
            g = model.geom(geom).id
            if model.geom_type[g] != mujoco.mjtGeom.mjGEOM_BOX:
                raise ConfigError(f"the scene's {geom} is not a box; surface_top_z reads boxes")
            pos, size = model.geom_pos[g], model.geom_size[g]
            self.surfaces.append((pos[:2].copy(), size[:2].copy(), float(pos[2] + size[2])))
        self.surfaces.sort(key=lambda s: -s[2])

    def hand_poses(self, arm_q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``arm_q`` (T, 6) rad (arm_joint_1..6) -> (R (T, 3, 3) hand_base -> world, p (T, 3) m, world)."""
        arm_q = np.asarray(arm_q, float).reshape(-1, 6)
        rot, pos = np.empty((len(arm_q), 3, 3)), np.empty((len(arm_q), 3))
        for k, q in enumerate(arm_q):
            self.data.qpos[self.qpos_adr] = q
            mujoco.mj_kinematics(self.model, self.data)
            rot[k] = self.data.xmat[self.hand_body].reshape(3, 3)
            pos[k] = self.data.xpos[self.hand_body]
        return rot, pos

    def outside_range(self, arm_q: np.ndarray, slack: float = 1e-3) -> np.ndarray:
        """(T,) bool: a joint beyond the model's range (by more than ``slack`` rad): not this arm's reading."""
        q = np.asarray(arm_q, float).reshape(-1, 6)
        low, high = self.joint_range[:, 0] - slack, self.joint_range[:, 1] + slack
        return ((q < low) | (q > high)).any(axis=1)

    def surface_top_z(self, xy: np.ndarray) -> np.ndarray:
        """(...,) the top (world z, m) of the highest surface under each point ``xy`` (..., 2); -inf off them."""
        xy = np.asarray(xy, float)
        top = np.full(xy.shape[:-1], -np.inf)
        for centre, half, z in reversed(self.surfaces):  # lowest first, the higher one overwrites it
            over = (np.abs(xy - centre) <= half).all(axis=-1)
            top = np.where(over, z, top)
        return top


@functools.cache
def default_kinematics() -> ArmKinematics:
    """The pick scene's kinematics (compiled once per process)."""
    return ArmKinematics()


__all__ = ["ArmKinematics", "default_kinematics"]
