"""The SVH hand's couplings and position servos, read from the compiled model."""

from __future__ import annotations

import mujoco
import numpy as np

from hingelab.sim import names


class HandCoupling:
    """The 11 coupled joints: dependent = k * primary, from the model's joint equalities."""

    def __init__(self, model: mujoco.MjModel):
        self.pairs: list[tuple[int, int, float]] = []  # (dependent qpos adr, primary qpos adr, k)
        for i in range(model.neq):
            if model.eq_type[i] != mujoco.mjtEq.mjEQ_JOINT:
                continue
            dep, prim = model.eq_obj1id[i], model.eq_obj2id[i]
            if not model.joint(dep).name.startswith("svh_"):
                continue
            k = float(model.eq_data[i][1])
            self.pairs.append((model.jnt_qposadr[dep], model.jnt_qposadr[prim], k))

    def apply_to_qpos(self, data: mujoco.MjData) -> None:
        """Set every dependent joint from its primary (for kinematic posing and keyframes)."""
        for dep, prim, k in self.pairs:
            data.qpos[dep] = k * data.qpos[prim]


class HandActuators:
    """Index arrays for the 9 hand actuators and their primary joints."""

    def __init__(self, model: mujoco.MjModel):
        self.actuator_ids = np.array([model.actuator(a).id for a in names.HAND_ACTUATORS])
        joint_ids = [model.joint(j).id for j in names.HAND_PRIMARY_JOINTS]
        self.qpos_adr = np.array([model.jnt_qposadr[j] for j in joint_ids])
        self.qvel_adr = np.array([model.jnt_dofadr[j] for j in joint_ids])
        self.ctrl_low = model.actuator_ctrlrange[self.actuator_ids, 0].copy()
        self.ctrl_high = model.actuator_ctrlrange[self.actuator_ids, 1].copy()

    # take() with an index array returns a fresh array (a copy, never a view of MjData)
    def q(self, data: mujoco.MjData) -> np.ndarray:
        """(9,) primary joint positions, rad."""
        return data.qpos.take(self.qpos_adr)

    def qdot(self, data: mujoco.MjData) -> np.ndarray:
        """(9,) primary joint velocities, rad/s."""
        return data.qvel.take(self.qvel_adr)

    def clip_to_ctrl_range(self, targets: np.ndarray) -> np.ndarray:
        """(9,) servo targets (rad) clipped to the actuators' ctrlrange.

        The same values as ``np.clip`` for finite targets, without its dispatch overhead.
        """
        return np.minimum(np.maximum(targets, self.ctrl_low), self.ctrl_high)
