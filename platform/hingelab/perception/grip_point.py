"""The tweezer's grip point rebuilt from perception rather than read from the simulator.

The env's rule (``hingelab.sim.scripted.grip_point``: between the two tip sites, at the lower tip's
height) on tips placed by the registered tool pose (leg a's frame in hand_base) and the opening the
encoder's calibration reads off the smoothed latent, through the tweezer's hinge kinematics
(``ToolGeometry.tips_in_tool_frame``). Real-rig episodes get their reward's grip point this way
(``hingelab.training.real_demos``), and the ``scripted-perceived`` baseline acts on it.
"""

from __future__ import annotations

import numpy as np

from hingelab.perception.clouds import ToolGeometry


def grip_points_world(tool_pos_hand, tool_rot_hand, z_bar, hand_rot, hand_pos, calibration):
    """The grip point (world, m) of each step rebuilt from perception (module docstring), and the two
    tips (T, 3) each in the world: tips from the tool pose (T, 3), (T, 3, 3) in hand_base and the
    opening read off z_bar (T, 2); into the world by the hand's pose (T, 3, 3), (T, 3)."""

    opening = calibration.opening_rad(z_bar)
    tips = []
    for tip_tool in ToolGeometry.default().tips_in_tool_frame(opening):
        tip_hand = np.einsum("tij,tj->ti", tool_rot_hand, tip_tool) + tool_pos_hand
        tips.append(np.einsum("tij,tj->ti", hand_rot, tip_hand) + hand_pos)
    a, b = tips
    grip = 0.5 * (a + b)
    grip[:, 2] = np.minimum(a[:, 2], b[:, 2])  # scripted.grip_point's rule: at the lower tip's height
    return grip, a, b
