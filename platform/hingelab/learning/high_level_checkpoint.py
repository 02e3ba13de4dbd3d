"""Loading a high-level policy checkpoint (a stable-baselines3 SAC zip trained on ToolPick-v0), checked.

The pattern of ``hingelab.learning.low_level_checkpoint``: a missing file, a file that is not
an SB3 SAC zip, or a SAC zip of another env (for example the low-level policy
``assets/checkpoints/low_level.zip``: ToolShape-v0's dict observation and 9-D action) is a
one-line ``ConfigError``. ToolPick-v0's spaces: observation ``Box(14,)``, action ``Box(5,)``.
There is no shipped high-level checkpoint yet (``hingelab eval high`` says so).
"""

from __future__ import annotations

from pathlib import Path

from hingelab.errors import ConfigError

OBSERVATION_SHAPE = (14,)
ACTION_SHAPE = (5,)


def resolve_checkpoint(path) -> Path:
    """A zip file, or a folder holding ``model.zip`` (a run folder): the zip to load."""
    path = Path(path)
    if path.is_dir() and (path / "model.zip").is_file():
        path = path / "model.zip"
    if not path.is_file():
        raise ConfigError(f"no high-level checkpoint at {path}; give a stable-baselines3 SAC zip trained on "
                          "ToolPick-v0 (or use --baseline heuristic|scripted|random)")
    return path


def load_high_level_checkpoint(path):
    """A SAC zip trained on ToolPick-v0 (14-D observation, 5-D action), loaded on the CPU."""
    from hingelab.learning.checkpoints import load_sac_zip

    path = resolve_checkpoint(path)
    model = load_sac_zip(path)
    space = model.observation_space
    if getattr(space, "spaces", None) is not None or tuple(space.shape or ()) != OBSERVATION_SHAPE or \
            tuple(model.action_space.shape or ()) != ACTION_SHAPE:
        shapes = {k: tuple(v.shape) for k, v in getattr(space, "spaces", {}).items()} or tuple(space.shape or ())
        raise ConfigError(f"{path} does not match ToolPick-v0 (observation {shapes}, action "
                          f"{tuple(model.action_space.shape or ())}; ToolPick-v0 has observation {OBSERVATION_SHAPE}, "
                          f"action {ACTION_SHAPE}); give a high-level checkpoint trained on hingelab/ToolPick-v0")
    return model


__all__ = ["load_high_level_checkpoint", "resolve_checkpoint", "OBSERVATION_SHAPE", "ACTION_SHAPE"]
