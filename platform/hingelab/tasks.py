"""The platform's three tasks as a contract: their Gymnasium ids, time limits and the scales of
ToolPick-v0's action and observation that policies are trained and checked against.

The envs (``hingelab.envs``) implement them; policies, rollouts and learners read them from here,
so a layer below the envs (``hingelab.policies``) can check a checkpoint against a task without
importing the env. ``register_envs`` registers the ids with Gymnasium by entry-point strings
(``import hingelab`` arranges it: at once if Gymnasium is already imported, else as Gymnasium's import ends,
so that a command that never touches Gymnasium, ``hingelab --help``, pays for neither it nor NumPy): the env
classes load on the first ``gymnasium.make``.
"""

from __future__ import annotations

import importlib.abc
import importlib.util
import sys

TOOL_SHAPE_ID = "hingelab/ToolShape-v0"
TOOL_PICK_ID = "hingelab/ToolPick-v0"
TOOL_PICK_FLAT_ID = "hingelab/ToolPickFlat-v0"
TOOL_SHAPE_EPISODE_STEPS = 50
TOOL_SHAPE_SUCCESS_GAP_MM = 2.0  # ToolShape-v0 succeeds within this tip gap of the goal, held over its last 0.5 s

# ToolPick-v0's action: the latent goal in units of Z_SCALE and the hand velocity in units of MAX_SPEED
Z_SCALE = 3.0
MAX_SPEED = 0.08  # m/s
# ToolPick-v0's observation: the tool's pose (position, m, and Euler angles, rad, hand frame), z_bar, then
# the object's centre (hand frame, m)
OBSERVED_TOOL_POSE = slice(0, 6)
OBSERVED_TOOL_POSITION = slice(0, 3)
OBSERVED_Z = slice(6, 8)
OBSERVED_OBJECT = slice(8, 11)
TARGET_HEIGHT = 0.05  # m: ToolPick-v0's target is this far above the object's start (world z)
TOOL_STATE_ALPHA = 0.9  # the paper's smoothing of the tool state (perception's and the high level's)
HIGH_LEVEL_ACTION_SHAPE = (5,)
HIGH_LEVEL_ACTION_NAMES = ("z_goal_0", "z_goal_1", "velocity_x", "velocity_y", "velocity_z")
LOW_LEVEL_ACTION_SHAPE = (9,)
LOW_LEVEL_OBSERVATION_DIM = 26  # hand q and q-dot (18), tool v and omega (6), z (2); the goal z apart


def observation_dim(observe_extent: bool = False) -> int:
    """ToolPick-v0's observation size: 14, and 3 more with the object's extent (``observe_extent``)."""
    return 17 if observe_extent else 14


FLAT_FINGERS = 9  # ToolPickFlat-v0 moves the 9 SVH channels itself (no latent goal, no low level)


def task_spaces(env_id: str, observe_extent: bool = False) -> tuple | None:
    """(observation_space, action_space) of the task ``env_id`` (what its env sets), None for another id.

    Only ``observe_extent`` (ToolPick-v0, ToolPickFlat-v0) changes a space; the envs take their
    spaces from here, so an export can state them without building an env.
    """
    import numpy as np
    from gymnasium import spaces

    box = spaces.Box
    if env_id == TOOL_SHAPE_ID:
        observation = spaces.Dict({
            "observation": box(-np.inf, np.inf, (LOW_LEVEL_OBSERVATION_DIM,), np.float64),
            "achieved_goal": box(-np.inf, np.inf, (2,), np.float64),
            "desired_goal": box(-np.inf, np.inf, (2,), np.float64),
        })
        return observation, box(-1.0, 1.0, LOW_LEVEL_ACTION_SHAPE, np.float32)
    if env_id == TOOL_PICK_ID:
        return (box(-np.inf, np.inf, (observation_dim(observe_extent),), np.float64),
                box(-1.0, 1.0, HIGH_LEVEL_ACTION_SHAPE, np.float32))
    if env_id == TOOL_PICK_FLAT_ID:  # ToolPick-v0's observation and the fingers' q and q-dot; fingers and hand velocity
        return (box(-np.inf, np.inf, (observation_dim(observe_extent) + 2 * FLAT_FINGERS,), np.float64),
                box(-1.0, 1.0, (FLAT_FINGERS + 3,), np.float32))
    return None


def register_envs() -> None:
    import gymnasium as gym

    if TOOL_SHAPE_ID not in gym.registry:
        gym.register(id=TOOL_SHAPE_ID, entry_point="hingelab.envs.tool_shape:ToolShapeEnv",
                     max_episode_steps=TOOL_SHAPE_EPISODE_STEPS)
    if TOOL_PICK_ID not in gym.registry:
        # the 200-step limit lives in the env (privileged steps count too)
        gym.register(id=TOOL_PICK_ID, entry_point="hingelab.envs.tool_pick:ToolPickEnv")
    if TOOL_PICK_FLAT_ID not in gym.registry:  # its 200-step limit lives in the env too
        gym.register(id=TOOL_PICK_FLAT_ID, entry_point="hingelab.envs.tool_pick_flat:ToolPickFlatEnv")


class _RegisterAfterGymnasium(importlib.abc.MetaPathFinder):
    """An import hook: finds ``gymnasium`` as the other finders do, and registers the envs as soon as the package
    has run (``gymnasium.envs.registration`` is loaded by then), then leaves. It stays until then, so a spec that
    is only looked up (``importlib.util.find_spec("gymnasium")``) and never run does not use it up."""

    def find_spec(self, name, path=None, target=None):
        if name != "gymnasium":
            return None
        sys.meta_path.remove(self)  # the other finders, without coming back here
        try:
            spec = importlib.util.find_spec(name)
        finally:
            sys.meta_path.insert(0, self)
        if spec is None or spec.loader is None or not hasattr(spec.loader, "exec_module"):
            return spec
        run = spec.loader.exec_module

        def run_then_register(module):
            run(module)
            if self in sys.meta_path:
                sys.meta_path.remove(self)
            register_envs()

        spec.loader.exec_module = run_then_register
        return spec


def register_envs_with_gymnasium() -> None:
    """Register the envs now if Gymnasium is imported, else when it is (``import hingelab`` calls this)."""
    if "gymnasium" in sys.modules:
        register_envs()
    elif not any(isinstance(f, _RegisterAfterGymnasium) for f in sys.meta_path):
        sys.meta_path.insert(0, _RegisterAfterGymnasium())


__all__ = ["TOOL_SHAPE_ID", "TOOL_PICK_ID", "TOOL_PICK_FLAT_ID", "TOOL_SHAPE_EPISODE_STEPS",
           "TOOL_SHAPE_SUCCESS_GAP_MM", "Z_SCALE", "MAX_SPEED", "OBSERVED_OBJECT", "OBSERVED_TOOL_POSITION",
           "OBSERVED_TOOL_POSE", "OBSERVED_Z", "TARGET_HEIGHT", "TOOL_STATE_ALPHA",
           "HIGH_LEVEL_ACTION_SHAPE", "LOW_LEVEL_ACTION_SHAPE", "LOW_LEVEL_OBSERVATION_DIM", "FLAT_FINGERS",
           "observation_dim", "register_envs", "register_envs_with_gymnasium", "task_spaces"]
