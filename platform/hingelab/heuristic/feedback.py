"""The size-free heuristic: the privileged heuristic's arm motion without the object's size.

``PrivilegedHeuristic`` opens to the object's width, grips at its mid-height and closes the hinge
to its contact angle minus a squeeze: all three come from the object's size, which the high level
never observes. Behaviour cloning of it on mixed sizes learns their average and misses the large
ones (``analysis/high-level/README.md``). ``FeedbackHeuristic`` decides only from what a high level
can see:

    open     to one width for every object (``open_width``: the largest, 25 mm, plus the margin;
             at most the finger synergy's widest, 0.262 rad)
    above,   the grip height is the object's observed centre (``ToolPickEnv.observed_object_centre``),
    descend  at least ``min_grip_height`` above the platform, as the heuristic's
    close    the hinge command closes at the heuristic's rate and never more than ``feedback_squeeze``
             below the opening the tool is perceived at (the encoder's latent through its
             calibration); against an object the perceived opening stops, so the command settles
             ``feedback_squeeze`` below the object's width, whatever that width is
    carry,   as the heuristic's, with the hinge command kept
    hold

The squeeze is chosen among several tried on ``eval high`` over the shipped low level: a smaller
one misses grasps of the small objects, a larger one lets objects slip and drops the tool (the
figures are in ``analysis/high-level/README.md``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from hingelab.heuristic.controller import Command, HeuristicConfig, PrivilegedHeuristic
from hingelab.sim import scripted
from hingelab.sim.core import SimCore
from hingelab.sim.finger_synergy import FingerSynergy
from hingelab.sim.objects import ObjectSpec
from hingelab.sim.privileged import PrivilegedState


@dataclass(frozen=True)
class FeedbackConfig(HeuristicConfig):
    open_width: float = 0.033  # m: the largest object (25 mm) plus open_margin
    feedback_squeeze: float = 0.08  # rad the hinge command stays below the perceived opening, at most
    min_command: float = 0.0  # rad: the hinge command's floor (closed)
    close_steps: int = 20  # the wider start needs more steps to close than the heuristic's 12


class FeedbackHeuristic(PrivilegedHeuristic):
    """Decides one ``Command`` per step without the object's size (module doc).

    ``perceived_opening`` returns the tool's opening (rad) as the high level perceives it now.
    """

    def __init__(self, sim: SimCore, synergy: FingerSynergy, obj: ObjectSpec,
                 perceived_opening: Callable[[], float], config: FeedbackConfig | None = None):
        config = config or FeedbackConfig()
        super().__init__(sim, synergy, obj, config)
        self.perceived_opening = perceived_opening
        self.open_theta = min(float(np.arcsin(min(1.0, config.open_width / scripted.TOOL_TIP_X))),
                              synergy.theta_range[1])
        # the observed position is the object's centre (ToolPickEnv.observed_object_centre)
        self.centre_height = obj.centre_height

    def _grip_target(self, state: PrivilegedState) -> np.ndarray:
        p = state.object_pos_world.copy()
        p[2] = max(p[2] + self.centre_height, self.base_height + self.config.min_grip_height)
        return p

    def act(self, state: PrivilegedState) -> Command:
        if self.phase != "close":
            if self.phase == "carry" and self.phase_steps == 0:
                self.contact_theta = self.grasp_theta + self.config.finger_squeeze  # the fingers' carry pose
            return super().act(state)
        c = self.config
        self.phase_steps += 1
        opening = float(self.perceived_opening())
        self.hinge_cmd = min(self.hinge_cmd, max(self.hinge_cmd - 0.015, opening - c.feedback_squeeze, c.min_command))
        if self.phase_steps >= c.close_steps:
            self.grasp_theta = opening
            self._enter("carry")
        return Command(np.zeros(3), self.hinge_cmd, self.synergy.targets(self.open_theta), "close")


__all__ = ["FeedbackConfig", "FeedbackHeuristic"]
