"""The privileged heuristic: knows the tip and object positions, commands the hinge directly.

Paper, "Generating Replay Buffer with Privilege Heuristic Policy": a proportional
controller brings the tweezer to the object, the hinge is commanded closed until the
inner faces match the object's size, and the tool carries the object to the target.

Phases, one decision per 20 Hz step:

    open     fingers (synergy) and hinge servo open the tips to the object's width + margin
    above    grip point to 3 cm above the object's grip height
    descend  grip point down to the grip height: the object's mid-height, but at least
             8 mm up so the pads clear the platform
    close    hinge servo closes toward the contact angle minus a squeeze; the fingers follow
             the synergy so leg b stays held
    carry    object to the target (5 cm above where it started), on the object's position
    hold     keep still once the object is within the success radius

A grasp that loses the object (it falls back) re-opens and tries again from ``above``
without resetting the object: the attempts the paper counts.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.objects import ObjectSpec
from hingelab.sim.privileged import PrivilegedState

PHASES = ("open", "above", "descend", "close", "carry", "hold")


@dataclass(frozen=True)
class HeuristicConfig:
    approach_height: float = 0.03  # m above the grip height before descending
    min_grip_height: float = 0.008  # m: the pads reach 6 mm below the tip sites
    position_gain: float = 3.0  # 1/s, proportional approach
    max_speed: float = 0.08  # m/s
    carry_speed: float = 0.04  # m/s, slower with the object held
    open_margin: float = 0.008  # m added to the object's width when opening
    squeeze: float = 0.05  # rad the hinge servo aims past the contact angle
    finger_squeeze: float = 0.03  # rad the finger synergy aims past the contact angle
    close_steps: int = 12  # steps the hinge servo closes before carrying
    # at most this fraction of the contact angle as squeeze (None: the full squeeze for every size): the
    # full 0.05 rad past a 0.04 rad contact closes the tips completely and squeezes a small object out
    max_squeeze_fraction: float | None = None
    close_tracking: bool = False  # keep the grip point on the object while closing (else hold still)
    reach_tolerance: float = 0.003  # m
    success_radius: float = 0.01  # m (paper: object within 1 cm of the target)
    drop_height: float = 0.01  # m: the object back within this of its start height = dropped


@dataclass
class Command:
    arm_velocity: np.ndarray  # (3,) m/s, world frame
    hinge_target: float | None  # rad, privileged servo; None = off
    hand_targets: np.ndarray  # (9,) rad, absolute finger targets
    phase: str


class PrivilegedHeuristic:
    """Decides one ``Command`` per step from the privileged state (see the module doc)."""

    def __init__(self, sim: SimCore, synergy: FingerSynergy, obj: ObjectSpec,
                 config: HeuristicConfig | None = None):
        self.sim = sim
        self.synergy = synergy
        self.config = config or HeuristicConfig()
        # grip at mid-height, but high enough that the tip pads clear the platform
        self.grip_offset = max(obj.height / 2, self.config.min_grip_height)
        object_width = obj.width_at(self.grip_offset)
        self.object_width = object_width
        self.contact_theta = float(np.arcsin(min(1.0, object_width / scripted.TOOL_TIP_X)))
        self.squeeze, self.finger_squeeze = self.config.squeeze, self.config.finger_squeeze
        if self.config.max_squeeze_fraction is not None:
            cap = self.config.max_squeeze_fraction * self.contact_theta
            self.squeeze, self.finger_squeeze = min(self.squeeze, cap), min(self.finger_squeeze, cap)
        open_width = object_width + self.config.open_margin
        self.open_theta = min(float(np.arcsin(min(1.0, open_width / scripted.TOOL_TIP_X))),
                              synergy.theta_range[1])
        self.phase = "open"
        self.attempt = 1
        self.phase_steps = 0
        self.object_start: np.ndarray | None = None
        self.base_height = 0.0
        self.target: np.ndarray | None = None
        self.hinge_cmd: float | None = None
        # where the grip point is taken from: the simulator's tip sites, or (a baseline acting on what a policy
        # observes) a callable returning it rebuilt from perception
        self.grip_point = self._simulated_grip_point

    def _simulated_grip_point(self) -> np.ndarray:
        return scripted.grip_point(self.sim)

    def reset(self, state: PrivilegedState, target: np.ndarray) -> None:
        self.phase, self.attempt, self.phase_steps = "open", 1, 0
        self.object_start = state.object_pos_world.copy()
        self.base_height = scripted.platform_top(self.sim.model)
        self.target = np.asarray(target, float)
        self.hinge_cmd = None

    def _grip_target(self, state: PrivilegedState) -> np.ndarray:
        p = state.object_pos_world.copy()
        p[2] = self.base_height + self.grip_offset
        return p

    def _to(self, target: np.ndarray, speed: float) -> tuple[np.ndarray, float]:
        error = target - self.grip_point()
        return np.clip(self.config.position_gain * error, -speed, speed), float(np.linalg.norm(error))

    def _enter(self, phase: str) -> None:
        self.phase, self.phase_steps = phase, 0

    def act(self, state: PrivilegedState) -> Command:
        c = self.config
        self.phase_steps += 1
        velocity = np.zeros(3)
        fingers_theta = self.open_theta
        if self.phase == "open":
            self.hinge_cmd = self.open_theta
            if abs(state.hinge_angle - self.open_theta) < 0.02 or self.phase_steps > 15:
                self._enter("above")
        elif self.phase == "above":
            velocity, error = self._to(self._grip_target(state) + [0, 0, c.approach_height], c.max_speed)
            if error < c.reach_tolerance:
                self._enter("descend")
        elif self.phase == "descend":
            velocity, error = self._to(self._grip_target(state), c.max_speed / 2)
            if error < c.reach_tolerance / 2 or self.phase_steps > 60:
                self._enter("close")
                self.hinge_cmd = state.hinge_angle
        elif self.phase == "close":
            if c.close_tracking:  # the closing leg drags the grip point sideways; one tip would push the object
                velocity, _ = self._to(self._grip_target(state), c.max_speed / 2)
            self.hinge_cmd = max(self.contact_theta - self.squeeze, self.hinge_cmd - 0.015)
            fingers_theta = max(self.hinge_cmd, self.contact_theta - self.finger_squeeze)
            if self.phase_steps >= c.close_steps:
                self._enter("carry")
        elif self.phase in ("carry", "hold"):
            fingers_theta = self.contact_theta - self.finger_squeeze
            error = self.target - state.object_pos_world
            velocity = np.clip(c.position_gain * error, -c.carry_speed, c.carry_speed)
            if self._dropped(state):
                self.attempt += 1
                self._enter("open")
                self.hinge_cmd = self.open_theta
            elif np.linalg.norm(error) < c.success_radius:
                self.phase = "hold"
        return Command(velocity, self.hinge_cmd, self.synergy.targets(fingers_theta), self.phase)

    def _dropped(self, state: PrivilegedState) -> bool:
        """After some carrying, the object is back down near where it started, or far off the tips."""
        if self.phase_steps < 15:
            return False
        low = state.object_pos_world[2] < self.object_start[2] + self.config.drop_height
        away = np.linalg.norm(state.object_pos_world - self.grip_point()) > 0.04
        return bool(low or away)
