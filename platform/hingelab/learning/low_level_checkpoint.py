"""Loading a low-level policy checkpoint (a ``hingelab train low`` SAC zip), checked against the task.

Shared by ``PolicyLowLevel`` (ToolPick-v0's low level) and the goal-region experts
(``hingelab.learning.goal_experts``), which load one such checkpoint per expert.
"""

from __future__ import annotations

from pathlib import Path

from hingelab.errors import ConfigError


def load_sac_checkpoint(path: Path, encoder=None):
    """A ``hingelab train low`` SAC zip, checked: ToolShape-v0's spaces, and latents of ``encoder``
    (default: the shipped one; a checkpoint that recorded another encoder's fingerprint is refused)."""
    import gymnasium as gym
    import numpy as np

    from hingelab.learning.checkpoints import load_sac_zip
    from hingelab.learning.safe_sb3 import read_plain_data

    _, described = read_plain_data(path)
    box = gym.spaces.Box
    observation = gym.spaces.Dict({"achieved_goal": box(-np.inf, np.inf, (2,), np.float64),
                                   "desired_goal": box(-np.inf, np.inf, (2,), np.float64),
                                   "observation": box(-np.inf, np.inf, (26,), np.float64)})
    try:
        model = load_sac_zip(path, observation, box(-1.0, 1.0, (9,), np.float32))
    except ConfigError as exc:
        if "do not fit" not in str(exc):
            raise
        recorded = {k: (described.get(k) or {}) for k in ("observation_space", "action_space")}
        raise ConfigError(f"{path} does not match ToolShape-v0 (observation "
                          f"{recorded['observation_space'].get('spaces') or recorded['observation_space'].get('_shape')}, "
                          f"action {recorded['action_space'].get('_shape')}); give a checkpoint from "
                          "`hingelab train low`") from exc
    trained_with = (getattr(model, "hingelab_provenance", None) or {}).get("encoder_fingerprint")
    if trained_with is not None:  # checkpoints made before the fingerprint was recorded: not checked
        from hingelab.perception.encoder import shipped_encoder

        current = encoder if encoder is not None else shipped_encoder()
        if not current.accepts(trained_with):
            raise ConfigError(f"{path} learned from the latents of another tool encoder (fingerprint "
                              f"{trained_with}, this env's is {current.fingerprint}); retrain it with "
                              "`hingelab train low` on this encoder")
    return model


DEFAULT_ACTION_SCALE = 0.05  # ToolShape-v0's default: what checkpoints that record none were trained with


def recorded_env_arguments(model) -> dict:
    """The ToolShape-v0 arguments a low-level checkpoint was trained with: its record (``env_kwargs``,
    written since the training core), or, for older checkpoints, rebuilt from its config (the reward's
    weights and the episode length; the defaults where the config is silent)."""
    from hingelab.envs.rewards import LowLevelRewardConfig

    provenance = getattr(model, "hingelab_provenance", None) or {}
    if isinstance(provenance.get("env_kwargs"), dict):
        return dict(provenance["env_kwargs"])
    trained = provenance.get("config", {})
    return {"use_effort": trained.get("use_effort", True),
            "effort_weight": trained.get("effort_weight", LowLevelRewardConfig().c2),
            "drift_weight": trained.get("drift_weight", 0.0),
            "max_episode_steps": trained.get("max_episode_steps", 50)}


TRAINING_ONLY_ARGUMENTS = ("goal_sampling", "goal_openings")  # a run's training goals, not an evaluation's


def evaluation_env_arguments(model) -> dict:
    """``recorded_env_arguments`` without the training goals: held-out goals come from the whole
    reachable range, whatever band the policy was trained on."""
    return {k: v for k, v in recorded_env_arguments(model).items() if k not in TRAINING_ONLY_ARGUMENTS}


def recorded_action_scale(model) -> float:
    """rad per step of a full action, as the checkpoint records it (older ones: ToolShape-v0's default)."""
    provenance = getattr(model, "hingelab_provenance", None) or {}
    if "action_scale" in provenance:
        return float(provenance["action_scale"])
    return float(recorded_env_arguments(model).get("action_scale", DEFAULT_ACTION_SCALE))


__all__ = ["load_sac_checkpoint", "recorded_env_arguments", "evaluation_env_arguments", "recorded_action_scale", "DEFAULT_ACTION_SCALE"]
