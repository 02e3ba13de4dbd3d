"""The tool pose ToolPick-v0's high level observes: the tracked pose, smoothed, in one of three forms.

The paper's synthesized clouds carry a per-episode pose error (up to 2 cm, 30 degrees: a calibration error, fixed
for the episode), the camera's a hand-eye error of about 1 cm; either moves the tracked pose by a constant. The
forms (``TOOL_POSITIONS``; the env's ``tool_position`` and ``hingelab trial``'s ``--tool-position``):

- ``"observed"``: the tracked position and Euler angles (extrinsic x-y-z), the paper's;
- ``"anchored"``: the tracked position's change since the episode's first frame placed on the tracker's nominal
  in-hand position (the true in-hand start, 1-2 mm from nominal, unseen); the Euler angles as tracked;
- ``"relative"``: the whole tracked pose's change since the first frame, taken in the tool's own first-frame axes
  (where a constant calibration rotation cancels: ``R_0^T R_t``), placed on the nominal in-hand pose. Its Euler
  angles are those of the rotation away from the nominal pose, near zero. The nominal pose itself sits at
  Euler angles of about (3.12, -0.25, -3.14) rad, where a tracked angle flips between +pi and -pi with the
  tracker's noise and a linear average across the flip is no rotation at all; near zero nothing flips;
- ``"nominal"``: no tracking: the nominal in-hand pose at every step, in the relative form's terms (Euler angles
  zero). What a policy that takes the tool to sit where it was put observes; a baseline for what tracking adds.

The pose is smoothed with the paper's alpha (0.9) each step, the first frame unsmoothed. The env and the robot
controller both observe through ``ObservedToolPose``, so a policy sees the same form in simulation and on a rig.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from hingelab.errors import ConfigError
from hingelab.perception.registration import EULER_SEQUENCE, euler_xyz
from hingelab.tasks import TOOL_STATE_ALPHA

OBSERVED, ANCHORED, RELATIVE, NOMINAL = "observed", "anchored", "relative", "nominal"
TOOL_POSITIONS = (OBSERVED, ANCHORED, RELATIVE, NOMINAL)


def check_tool_position(value: str, where: str = "tool position") -> str:
    """``value`` if it is one of ``TOOL_POSITIONS``, else a one-line ConfigError starting with ``where``."""
    if value not in TOOL_POSITIONS:
        raise ConfigError(f"{where} {value!r} is unknown; choose one of {', '.join(TOOL_POSITIONS)}")
    return value


def anchored_tool_pose(pose: np.ndarray, anchor: np.ndarray, nominal) -> np.ndarray:
    """``pose`` (position, Euler angles) with its position moved to ``nominal`` plus its change since ``anchor``
    (the first frame's position): the ``"anchored"`` form."""
    return np.concatenate([np.asarray(nominal, float) + pose[:3] - anchor, pose[3:]])


def relative_tool_pose(rot: np.ndarray, pos: np.ndarray, first: tuple[np.ndarray, np.ndarray],
                       nominal: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The ``"relative"`` form of one tracked pose (R (3, 3), t (3,)) given the first frame's and the nominal
    in-hand pose: position ``t_nom + R_nom R_0^T (t - t_0)``, Euler angles of ``R_0^T R`` (module docstring)."""
    rot_0, pos_0 = first
    rot_nom, pos_nom = nominal
    change = rot_0.T @ rot
    position = np.asarray(pos_nom, float) + rot_nom @ (rot_0.T @ (np.asarray(pos, float) - pos_0))
    return np.concatenate([position, euler_xyz(change.reshape(1, 3, 3))[0]])


def observed_tool_rotation(euler: np.ndarray, tool_position: str, nominal_rotation: np.ndarray) -> np.ndarray:
    """The tool's rotation in the hand frame (3, 3) that an observation's Euler angles stand for, in its form."""
    rot = Rotation.from_euler(EULER_SEQUENCE, np.asarray(euler, float)).as_matrix()
    return nominal_rotation @ rot if tool_position in (RELATIVE, NOMINAL) else rot


class ObservedToolPose:
    """The smoothed tool pose of one episode, in the form ``tool_position``: ``reset`` on the first frame, ``update``
    on each next one, ``observation`` (6,) position (m) and Euler angles (rad), hand frame."""

    def __init__(self, tool_position: str, nominal: tuple[np.ndarray, np.ndarray], alpha: float = TOOL_STATE_ALPHA):
        self.tool_position = check_tool_position(tool_position)
        self.nominal = (np.asarray(nominal[0], float), np.asarray(nominal[1], float))
        self.alpha = alpha
        self._smoothed = np.zeros(6)
        self._first: tuple[np.ndarray, np.ndarray] | None = None

    def _raw(self, rot: np.ndarray, pos: np.ndarray, euler: np.ndarray) -> np.ndarray:
        if self.tool_position == RELATIVE:
            return relative_tool_pose(rot, pos, self._first, self.nominal)
        if self.tool_position == NOMINAL:
            return np.concatenate([self.nominal[1], np.zeros(3)])
        return np.concatenate([np.asarray(pos, float), np.asarray(euler, float)])

    def reset(self, rot: np.ndarray, pos: np.ndarray, euler: np.ndarray) -> np.ndarray:
        self._first = (np.asarray(rot, float).copy(), np.asarray(pos, float).copy())
        self._smoothed = self._raw(rot, pos, euler)
        return self.observation()

    def update(self, rot: np.ndarray, pos: np.ndarray, euler: np.ndarray) -> np.ndarray:
        if self._first is None:
            return self.reset(rot, pos, euler)
        self._smoothed = self.alpha * self._raw(rot, pos, euler) + (1 - self.alpha) * self._smoothed
        return self.observation()

    def observation(self) -> np.ndarray:
        if self.tool_position == ANCHORED:
            return anchored_tool_pose(self._smoothed, self._first[1], self.nominal[1])
        return self._smoothed.copy()

    def rotation(self, observation: np.ndarray) -> np.ndarray:
        """The hand-frame rotation an observation's Euler angles (its entries 3:6) stand for in this form."""
        return observed_tool_rotation(np.asarray(observation)[3:6], self.tool_position, self.nominal[0])


__all__ = ["OBSERVED", "ANCHORED", "RELATIVE", "NOMINAL", "TOOL_POSITIONS", "check_tool_position", "anchored_tool_pose",
           "relative_tool_pose", "observed_tool_rotation", "ObservedToolPose"]
