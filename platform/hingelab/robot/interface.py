"""The robot interface: the few things the hierarchical controller reads and commands.

Reads, once per 20 Hz control period (``RobotReadings``): the joint states of the arm (6) and
the hand (9 actuated channels, the SVH driver's order: ``hingelab.sim.names.HAND_ACTUATORS``),
the hand base's pose in the arm's base frame (the arm's forward kinematics), a depth camera frame
with its intrinsics and its pose in ``hand_base`` (``hingelab.camera.CameraFrame``), and the
object estimate (its centre in the arm's base frame and its extent, from the camera's object
segmentation on a real rig).

Commands, one per control period (``Robot.command``): a linear velocity of the hand base in its
own frame (m/s; the arm's Jacobian controller turns it into joint velocities) and the 9 hand
channels' position targets as changes from their current positions (rad; the paper's low-level
action: target = current + change, the current position being the hand's own at the servo, not
the reading the controller saw).

A real driver plugs in here: a class with these methods (``start_trial``, ``command``, ``verdict``,
``close`` and the attributes below), built from the rig's ROS 2 topics or vendor SDKs (Jaka's
SDK for the arm, SCHUNK's SVH driver for the hand, the Azure Kinect SDK for the camera), with
``source = "real"``, registered under a name with ``register_robot(name, make)`` (``make(object,
size, max_steps)`` builds it, and ``make(..., object_perception=NAME)`` where the robot offers a choice of
object estimate, as the stand-in does; the stand-in registers ``sim`` this way): ``hingelab trial --robot NAME``
then drives it. ``verdict`` returns None on a real rig: the operator
judges each attempt (``hingelab trial --operator``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol

import numpy as np

from hingelab.camera import CameraFrame


@dataclass
class RobotReadings:
    stamp_s: float
    arm_position: np.ndarray  # (6,) rad
    arm_velocity: np.ndarray  # (6,) rad/s
    hand_position: np.ndarray  # (9,) rad, the actuated channels
    hand_velocity: np.ndarray  # (9,) rad/s
    hand_rotation: np.ndarray  # (3, 3) hand_base -> the arm's base frame
    hand_translation: np.ndarray  # (3,) hand_base's origin in the arm's base frame, m
    frame: CameraFrame
    object_centre: np.ndarray | None  # (3,) m, the arm's base frame; None if not seen
    object_extent: np.ndarray | None  # (3,) m, its bounding box along the base frame's axes
    # where a camera estimates the object (an object estimator): this frame's visible points (N, 3), m, base
    # frame, None when the frame gave none, and why (``hingelab.perception.object_estimate`` flags)
    object_points: np.ndarray | None = None
    object_flag: str | None = None

    def to_hand(self, point: np.ndarray) -> np.ndarray:
        """A point of the arm's base frame in hand_base."""
        return self.hand_rotation.T @ (np.asarray(point, float) - self.hand_translation)


@dataclass
class Verdict:
    """What a simulated rig knows of the trial (None on a real one): the env's one verdict and attempts."""

    success: bool
    attempt: int
    first_attempt_success: bool
    done: bool  # the trial is over (success, the tool dropped, the step limit)
    failure_reason: str | None = None


class Robot(Protocol):
    source: str  # "stand_in" or "real": the episodes' source
    arm_joint_names: tuple[str, ...]
    hand_joint_names: tuple[str, ...]

    def start_trial(self, seed: int) -> RobotReadings:
        """Set up a trial (the stand-in resets its scene; on a real rig the operator places the object)."""

    def command(self, hand_velocity: np.ndarray, hand_changes: np.ndarray) -> RobotReadings:
        """Apply one control period's command; the readings after it."""

    def verdict(self) -> Verdict | None:
        """The simulation's verdict so far, or None where only an operator can judge."""

    def close(self) -> None:
        """Release the robot (stop the arm, close the camera)."""


# name -> make(object, size, max_steps) -> Robot: what `hingelab trial --robot NAME` drives
ROBOTS: dict[str, Callable[..., Robot]] = {}


def register_robot(name: str, make: Callable[..., Robot]) -> None:
    ROBOTS[name] = make
