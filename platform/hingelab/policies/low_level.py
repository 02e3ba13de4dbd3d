"""Low-level policies: naming one (``resolve_low_level``) and loading a ``hingelab train low`` SAC zip,
checked against ToolShape-v0's spaces and the encoder the policy learned on.

Shared by ToolPick-v0's low level (``hingelab.envs.low_level``) and the goal-region experts
(``hingelab.policies.goal_experts``), which load one such checkpoint per expert.
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.errors import ConfigError
from hingelab.paths import ASSETS_DIR
from hingelab.perception.encoder import shipped_encoder
from hingelab.policies.sb3_zip import load_sac_zip, read_plain_data
from hingelab.tasks import LOW_LEVEL_ACTION_SHAPE, LOW_LEVEL_OBSERVATION_DIM

SHIPPED_LOW_LEVEL = ASSETS_DIR / "checkpoints" / "low_level_experts.json"  # the default: experts by goal band
SHIPPED_LOW_LEVEL_SAC = ASSETS_DIR / "checkpoints" / "low_level.zip"  # its expert for all but the closed goals


def resolve_low_level(spec: str | Path) -> str | Path:
    """"privileged", or the checkpoint file a low-level spec names ("policy": the shipped experts; a
    run folder: its model.zip); a missing one is a one-line ConfigError."""
    if str(spec) == "privileged":
        return "privileged"
    path = SHIPPED_LOW_LEVEL if str(spec) == "policy" else Path(spec)
    if not path.exists():
        raise ConfigError(f"low-level checkpoint {path} does not exist; give policy, privileged, or a checkpoint "
                          "from `hingelab train low` / `hingelab compose low`")
    if path.is_dir():
        if not (path / "model.zip").is_file():
            raise ConfigError(f"{path} is a folder without a model.zip; give a run folder, a checkpoints/step_* "
                              "folder or a .zip from `hingelab train low`")
        path = path / "model.zip"
    return path


def load_sac_checkpoint(path: Path, encoder=None):
    """A ``hingelab train low`` SAC zip, checked: ToolShape-v0's spaces, and latents of ``encoder``
    (default: the shipped one; a checkpoint that recorded another encoder's fingerprint is refused)."""
    _, described = read_plain_data(path)
    box = gym.spaces.Box
    observation = gym.spaces.Dict({"achieved_goal": box(-np.inf, np.inf, (2,), np.float64),
                                   "desired_goal": box(-np.inf, np.inf, (2,), np.float64),
                                   "observation": box(-np.inf, np.inf, (LOW_LEVEL_OBSERVATION_DIM,), np.float64)})
    try:
        model = load_sac_zip(path, observation, box(-1.0, 1.0, LOW_LEVEL_ACTION_SHAPE, np.float32))
    except ConfigError as exc:
        if "do not fit" not in str(exc):
            raise
        recorded = {k: (described.get(k) or {}) for k in ("observation_space", "action_space")}
        raise ConfigError(
            f"{path} does not match ToolShape-v0 (observation "
            f"{recorded['observation_space'].get('spaces') or recorded['observation_space'].get('_shape')}, "
            f"action {recorded['action_space'].get('_shape')}); give a checkpoint from "
            "`hingelab train low`") from exc
    trained_with = (getattr(model, "hingelab_provenance", None) or {}).get("encoder_fingerprint")
    if trained_with is not None:  # checkpoints made before the fingerprint was recorded: not checked
        current = encoder if encoder is not None else shipped_encoder()
        if not current.accepts(trained_with):
            raise ConfigError(f"{path} learned from the latents of another tool encoder (fingerprint "
                              f"{trained_with}, this env's is {current.fingerprint}); retrain it with "
                              "`hingelab train low` on this encoder")
    return model


DEFAULT_ACTION_SCALE = 0.05  # ToolShape-v0's default: what checkpoints that record none were trained with


def recorded_action_scale(model) -> float:
    """rad per step of a full action, as the checkpoint records it (older ones: ToolShape-v0's default)."""
    provenance = getattr(model, "hingelab_provenance", None) or {}
    if "action_scale" in provenance:
        return float(provenance["action_scale"])
    env_kwargs = provenance.get("env_kwargs")
    return float((env_kwargs if isinstance(env_kwargs, dict) else {}).get("action_scale", DEFAULT_ACTION_SCALE))


__all__ = ["load_sac_checkpoint", "recorded_action_scale", "resolve_low_level", "DEFAULT_ACTION_SCALE",
           "SHIPPED_LOW_LEVEL", "SHIPPED_LOW_LEVEL_SAC"]
