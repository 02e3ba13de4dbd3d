"""The task environments (registered with Gymnasium when ``hingelab`` is imported).

``hingelab/ToolShape-v0`` (low level), ``hingelab/ToolPick-v0`` (high level) and
``hingelab/ToolPickFlat-v0`` (the flat baseline: ToolPick-v0's task, one policy moving the
fingers and the hand); the env classes load lazily, so importing hingelab does not load
MuJoCo or torch.
"""

from __future__ import annotations

import gymnasium as gym

TOOL_SHAPE_ID = "hingelab/ToolShape-v0"
TOOL_PICK_ID = "hingelab/ToolPick-v0"
TOOL_PICK_FLAT_ID = "hingelab/ToolPickFlat-v0"
TOOL_SHAPE_EPISODE_STEPS = 50


def register_envs() -> None:
    if TOOL_SHAPE_ID not in gym.registry:
        gym.register(id=TOOL_SHAPE_ID, entry_point="hingelab.envs.tool_shape:ToolShapeEnv",
                     max_episode_steps=TOOL_SHAPE_EPISODE_STEPS)
    if TOOL_PICK_ID not in gym.registry:
        # the 200-step limit lives in the env (privileged steps count too)
        gym.register(id=TOOL_PICK_ID, entry_point="hingelab.envs.tool_pick:ToolPickEnv")
    if TOOL_PICK_FLAT_ID not in gym.registry:  # its 200-step limit lives in the env too
        gym.register(id=TOOL_PICK_FLAT_ID, entry_point="hingelab.envs.tool_pick_flat:ToolPickFlatEnv")
