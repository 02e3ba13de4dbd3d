"""Scripted motions on the sim core: the checks of the robot platform, and the demo.

Each routine drives ``SimCore`` through its public controls only (hand targets, arm
velocity, the privileged hinge command where named) and returns what it measured.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mujoco
import numpy as np

from hingelab.sim import names
from hingelab.sim.core import SimCore, StepResult
from hingelab.sim.finger_synergy import FingerSynergy

TOOL_TIP_X = 0.124  # m: tip sites along the tool's x axis (tweezer.xml)


def quat_angle_deg(q_a: np.ndarray, q_b: np.ndarray) -> float:
    """Angle between two orientations (w x y z quaternions), degrees."""
    dot = abs(float(np.dot(q_a, q_b)) / (np.linalg.norm(q_a) * np.linalg.norm(q_b)))
    return float(np.degrees(2 * np.arccos(min(1.0, dot))))


@dataclass
class ToolDrift:
    """Worst displacement of the tool in the hand since ``start``: mm and degrees."""

    start_pos: np.ndarray
    start_quat: np.ndarray
    max_mm: float = 0.0
    max_deg: float = 0.0

    def update(self, result: StepResult) -> None:
        s = result.state
        self.max_mm = max(self.max_mm, 1000 * float(np.linalg.norm(s.tool_pos_hand - self.start_pos)))
        self.max_deg = max(self.max_deg, quat_angle_deg(s.tool_quat_hand, self.start_quat))


def drift_from(sim: SimCore) -> ToolDrift:
    s = sim.privileged()
    return ToolDrift(s.tool_pos_hand.copy(), s.tool_quat_hand.copy())


def hold(sim: SimCore, seconds: float) -> ToolDrift:
    """Hold the current targets; how far the tool moves in the hand."""
    drift = drift_from(sim)
    for _ in range(int(round(seconds / sim.control_dt))):
        drift.update(sim.step())
    return drift


@dataclass
class FingerWorkResult:
    hinge_min: float
    hinge_max: float
    drift: ToolDrift
    hinge_trace: list[float] = field(default_factory=list)

    @property
    def hinge_range(self) -> float:
        return self.hinge_max - self.hinge_min


def work_tool_with_fingers(sim: SimCore, synergy: FingerSynergy, cycles: int = 1,
                           steps_per_sweep: int = 40) -> FingerWorkResult:
    """Open and close the hinge with the hand actuators alone (the hinge servo stays off)."""
    sim.release_hinge()
    drift = drift_from(sim)
    low, high = synergy.theta_range
    start = sim.privileged().hinge_angle
    path = np.concatenate([np.linspace(start, low, steps_per_sweep // 2)]
                          + [np.concatenate([np.linspace(low, high, steps_per_sweep),
                                             np.linspace(high, low, steps_per_sweep)])] * cycles
                          + [np.linspace(low, start, steps_per_sweep // 2)])
    trace = []
    for theta in path:
        sim.set_hand_targets(synergy.targets(theta))
        result = sim.step()
        drift.update(result)
        trace.append(result.state.hinge_angle)
    return FingerWorkResult(min(trace), max(trace), drift, trace)


def grip_point(sim: SimCore) -> np.ndarray:
    """World point the tweezer grips at: between the tip sites, at the lower tip's height."""
    d = sim.data
    a, b = d.site(names.TOOL_TIP_SITES[0]).xpos, d.site(names.TOOL_TIP_SITES[1]).xpos
    mid = 0.5 * (a + b)
    mid[2] = min(a[2], b[2])
    return mid


@dataclass
class MoveResult:
    error_m: float
    steps: int
    table_collision: bool
    drift: ToolDrift | None = None


def move_grip_to(sim: SimCore, target: np.ndarray, tolerance: float = 0.001, max_steps: int = 200,
                 gain: float = 3.0, max_speed: float = 0.08, drift: ToolDrift | None = None) -> MoveResult:
    """Proportional hand velocity until the grip point is within ``tolerance`` m of ``target``."""
    collided = False
    for step in range(1, max_steps + 1):
        error = np.asarray(target) - grip_point(sim)
        if np.linalg.norm(error) < tolerance:
            return MoveResult(float(np.linalg.norm(error)), step - 1, collided, drift)
        velocity = np.clip(gain * error, -max_speed, max_speed)
        result = sim.step(arm_velocity=velocity)
        collided |= result.state.table_collision
        if drift is not None:
            drift.update(result)
        if result.diverged:
            break
    return MoveResult(float(np.linalg.norm(np.asarray(target) - grip_point(sim))), max_steps, collided, drift)


def platform_top(model: mujoco.MjModel) -> float:
    g = model.geom("platform").id
    return float(model.geom_pos[g][2] + model.geom_size[g][2])


def platform_center(model: mujoco.MjModel) -> np.ndarray:
    return model.geom_pos[model.geom("platform").id][:2].copy()


def platform_in_hand(model: mujoco.MjModel, data: mujoco.MjData, hand_body: int) -> tuple | None:
    """The platform box in hand_base: (centre (3,) m, rotation (3, 3), size (3,) m full extents), or None
    for a scene without one. ``hand_body``: hand_base's body id."""
    try:
        g = model.geom("platform").id
    except KeyError:
        return None
    rot_hand = data.xmat[hand_body].reshape(3, 3)
    centre = rot_hand.T @ (data.geom_xpos[g] - data.xpos[hand_body])
    return centre, rot_hand.T @ data.geom_xmat[g].reshape(3, 3), 2.0 * model.geom_size[g]


@dataclass
class LiftResult:
    lifted_m: float
    hinge_at_grasp: float
    tool_object_contacts: int
    object_between_tips: bool
    table_collision_on_approach: bool


def grasp_and_lift(sim: SimCore, synergy: FingerSynergy, object_size: float, lift: float = 0.05,
                   squeeze: float = 0.05) -> LiftResult:
    """The privileged grasp: open with the fingers, approach, close the hinge servo to the
    object's width (the fingers follow), lift by ``lift`` m with the arm."""
    open_theta = synergy.theta_range[1]
    for _ in range(20):
        sim.set_hand_targets(synergy.targets(open_theta))
        sim.step()
    obj = sim.privileged().object_pos_world.copy()
    approach = move_grip_to(sim, obj + [0, 0, 0.03])
    down = move_grip_to(sim, obj)
    contact_theta = float(np.arcsin(min(1.0, object_size / TOOL_TIP_X)))
    theta = sim.privileged().hinge_angle
    result = None
    for _ in range(40):
        theta = max(contact_theta - squeeze, theta - 0.01)
        sim.set_hand_targets(synergy.targets(max(theta, contact_theta)))
        result = sim.step(hinge_target=theta)
    start_z = result.state.object_pos_world[2]
    hinge_at_grasp = result.state.hinge_angle
    move_grip_to(sim, grip_point(sim) + [0, 0, lift], max_speed=0.05, max_steps=120)
    for _ in range(20):
        result = sim.step()
    s = result.state
    between = _between_tips(s)
    return LiftResult(float(s.object_pos_world[2] - start_z), hinge_at_grasp, s.tool_object_contacts, between,
                      approach.table_collision or down.table_collision)


def _between_tips(state) -> bool:
    """The object's centre lies between the tip sites (within their gap, in the hand frame)."""
    a, b, p = state.tip_a_hand, state.tip_b_hand, state.object_pos_hand
    axis = b - a
    t = float(np.dot(p - a, axis) / max(np.dot(axis, axis), 1e-12))
    off_axis = np.linalg.norm(p - (a + t * axis))
    return 0.0 <= t <= 1.0 and off_axis < 0.012
