"""The task environments (registered with Gymnasium when ``hingelab`` is imported).

``hingelab/ToolShape-v0`` (low level), ``hingelab/ToolPick-v0`` (high level) and
``hingelab/ToolPickFlat-v0`` (the flat baseline: ToolPick-v0's task, one policy moving the
fingers and the hand); their ids and registration are the task contract of ``hingelab.tasks``.
The env classes load lazily, so importing hingelab does not load MuJoCo or torch.
"""

from __future__ import annotations

from hingelab.tasks import TOOL_PICK_FLAT_ID, TOOL_PICK_ID, TOOL_SHAPE_EPISODE_STEPS, TOOL_SHAPE_ID, register_envs

__all__ = ["TOOL_SHAPE_ID", "TOOL_PICK_ID", "TOOL_PICK_FLAT_ID", "TOOL_SHAPE_EPISODE_STEPS", "register_envs"]
