"""Arm control through the Jacobian: a hand-frame velocity becomes arm joint targets.

The paper commands the linear velocity of the hand frame relative to the arm base and
maps it to joint velocities with the pseudoinverse ``qdot = J+ v``. We use the full
6-row Jacobian of ``hand_base`` and ask for zero angular velocity plus a proportional
pull back to the orientation held at reset, so the tweezer keeps pointing down while the
hand translates (the paper's 3-row form leaves orientation free to drift). The
pseudoinverse is damped near singularities. Joint velocities are scaled down together
to the Zu 7's 180 deg/s bound and integrated into the position servos' targets.
"""

from __future__ import annotations

import functools

import mujoco
import numpy as np

from hingelab.sim import names

JOINT_SPEED_LIMIT = np.pi  # rad/s, every Zu 7 joint (vendor bound)
DAMPING = 1e-3  # damped least squares: lambda, in m (and rad)
ORIENTATION_GAIN = 5.0  # 1/s: pull back to the held orientation
MAX_LEAD = 0.05  # rad: how far a servo target may run ahead of the measured joint


def _arm_dofs(model: mujoco.MjModel) -> np.ndarray:
    return np.array([model.jnt_dofadr[model.joint(j).id] for j in names.ARM_JOINTS])


def hand_jacobian(model: mujoco.MjModel, data: mujoco.MjData, dofs: np.ndarray, hand_body: int | None = None,
                  out: np.ndarray | None = None) -> np.ndarray:
    """(6, 6): rows linear then angular velocity of hand_base (world frame), columns arm joints.

    ``hand_body`` (its id) and ``out`` (a (6, nv) buffer for all dofs) spare a per-step caller the
    name lookup and the allocations."""
    body = model.body(names.HAND_BASE_BODY).id if hand_body is None else hand_body
    full = np.zeros((6, model.nv)) if out is None else out
    mujoco.mj_jacBody(model, data, full[:3], full[3:], body)
    return full[:, dofs]


@functools.cache
def _identity(n: int) -> np.ndarray:
    """A shared read-only n x n identity (np.eye allocates one per call)."""
    eye = np.eye(n)
    eye.flags.writeable = False
    return eye


def damped_pinv_solve(jac: np.ndarray, twist: np.ndarray, damping: float = DAMPING) -> np.ndarray:
    """J^T (J J^T + lambda^2 I)^-1 twist."""
    jjt = jac @ jac.T + damping**2 * _identity(jac.shape[0])
    return jac.T @ np.linalg.solve(jjt, twist)


def orientation_error(rot_target: np.ndarray, rot_now: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame, rad) that takes rot_now to rot_target."""
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, (rot_target @ rot_now.T).ravel())
    vec = np.zeros(3)
    mujoco.mju_quat2Vel(vec, quat, 1.0)
    return vec


class ArmVelocityController:
    """Hand velocity (m/s, arm base frame) -> arm joint position targets, at the control rate."""

    def __init__(self, model: mujoco.MjModel):
        self.model = model
        self.dofs = _arm_dofs(model)
        self.qpos_adr = np.array([model.jnt_qposadr[model.joint(j).id] for j in names.ARM_JOINTS])
        self.actuator_ids = np.array([model.actuator(a).id for a in names.ARM_ACTUATORS])
        self.q_low = model.jnt_range[[model.joint(j).id for j in names.ARM_JOINTS], 0].copy()
        self.q_high = model.jnt_range[[model.joint(j).id for j in names.ARM_JOINTS], 1].copy()
        self.rot_hold = np.eye(3)
        self.q_target = np.zeros(6)
        self.hand_body = model.body(names.HAND_BASE_BODY).id
        self._jac_all_dofs = np.zeros((6, model.nv))  # hand_jacobian's buffer, reused every step

    def reset(self, data: mujoco.MjData) -> None:
        """Hold the current joint positions and hand orientation."""
        self.q_target = data.qpos[self.qpos_adr].copy()
        self.rot_hold = data.xmat[self.hand_body].reshape(3, 3).copy()
        data.ctrl[self.actuator_ids] = self.q_target

    def joint_velocities(self, data: mujoco.MjData, hand_velocity: np.ndarray) -> np.ndarray:
        """(6,) arm joint velocities (rad/s) for a hand_base linear velocity (m/s, base frame)."""
        jac = hand_jacobian(self.model, data, self.dofs, self.hand_body, self._jac_all_dofs)
        rot_now = data.xmat[self.hand_body].reshape(3, 3)
        twist = np.concatenate((hand_velocity, ORIENTATION_GAIN * orientation_error(self.rot_hold, rot_now)))
        qdot = damped_pinv_solve(jac, twist)
        peak = np.abs(qdot).max()
        if peak > JOINT_SPEED_LIMIT:
            qdot *= JOINT_SPEED_LIMIT / peak
        return qdot

    def command(self, data: mujoco.MjData, hand_velocity: np.ndarray, dt: float) -> None:
        """Integrate one control period of ``hand_velocity`` into the servo targets."""
        qdot = self.joint_velocities(data, hand_velocity)
        # integrate the target (so a steady servo error does not become drift), but keep
        # it within MAX_LEAD of the measured position so a blocked arm does not wind up
        q_now = data.qpos[self.qpos_adr]
        # np.minimum(np.maximum()) is np.clip's arithmetic without its dispatch overhead
        target = np.minimum(np.maximum(self.q_target + qdot * dt, q_now - MAX_LEAD), q_now + MAX_LEAD)
        self.q_target = np.minimum(np.maximum(target, self.q_low), self.q_high)
        data.ctrl[self.actuator_ids] = self.q_target


def solve_hand_pose(model: mujoco.MjModel, data: mujoco.MjData, pos: np.ndarray, rot: np.ndarray,
                    seeds: int = 64, iterations: int = 200, tol: float = 1e-6,
                    rng: np.random.Generator | None = None) -> np.ndarray:
    """Arm joint positions putting hand_base at (pos, rot) (world frame).

    Damped least-squares IK on kinematics only, within the joint limits, from data's arm
    pose and then from random seeds; of the solutions found, the one nearest data's arm
    pose. Raises ValueError if none converges.
    """
    rng = rng or np.random.default_rng(0)
    dofs = _arm_dofs(model)
    adr = np.array([model.jnt_qposadr[model.joint(j).id] for j in names.ARM_JOINTS])
    jnt = [model.joint(j).id for j in names.ARM_JOINTS]
    low, high = model.jnt_range[jnt, 0], model.jnt_range[jnt, 1]
    # seeds stay within +-pi of zero: the wide-range joints need no more
    seed_low, seed_high = np.maximum(low, -np.pi), np.minimum(high, np.pi)
    work = mujoco.MjData(model)
    body = model.body(names.HAND_BASE_BODY).id
    start = data.qpos[adr].copy()
    found, best_err = [], np.inf
    for k in range(seeds):
        work.qpos[:] = data.qpos
        work.qpos[adr] = start if k == 0 else rng.uniform(seed_low, seed_high)
        for _ in range(iterations):
            mujoco.mj_kinematics(model, work)
            mujoco.mj_comPos(model, work)
            err = np.concatenate([pos - work.xpos[body], orientation_error(rot, work.xmat[body].reshape(3, 3))])
            if np.linalg.norm(err) < tol:
                found.append(work.qpos[adr].copy())
                break
            jac = hand_jacobian(model, work, dofs)
            work.qpos[adr] = np.clip(work.qpos[adr] + damped_pinv_solve(jac, err, 1e-2), low, high)
        best_err = min(best_err, float(np.linalg.norm(err)))
    if not found:
        raise ValueError(f"arm IK did not converge (best residual {best_err:.2e})")
    return min(found, key=lambda q: float(np.linalg.norm(q - start)))
