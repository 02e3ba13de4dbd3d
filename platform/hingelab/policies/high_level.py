"""Loading a high-level policy checkpoint (a stable-baselines3 SAC zip trained on ToolPick-v0, or a phase
clone: ``hingelab.policies.phase_clone``), checked.

The pattern of ``hingelab.policies.low_level``: a missing file, a file that is not
an SB3 SAC zip, or a SAC zip of another env (for example the low-level policy
``assets/checkpoints/low_level.zip``: ToolShape-v0's dict observation and 9-D action) is a
one-line ``ConfigError``. ToolPick-v0's spaces: observation ``Box(14,)``, action ``Box(5,)``.

A high-level policy learned over one low level and one encoder: ``train high`` records them
(``training_context``: the low level's spec and sha256, the encoder's fingerprint), and
``check_context`` refuses the policy beside another trained low level or another encoder's latents
(the privileged low level is accepted under any policy: the reference that separates the levels'
shares of the failures).
The shipped one is ``assets/checkpoints/high_level.zip`` (``SHIPPED_HIGH_LEVEL``).
"""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np

from hingelab.errors import ConfigError
from hingelab.paths import ASSETS_DIR
from hingelab.perception.encoder import shipped_encoder, shipped_encoder_fingerprint
from hingelab.policies.goal_experts import file_sha256
from hingelab.policies.loading import register_policy_format
from hingelab.policies.low_level import load_sac_checkpoint, resolve_low_level
from hingelab.policies.phase_clone import PhaseClone, is_phase_clone
from hingelab.policies.residual import ResidualPolicy, is_residual_policy
from hingelab.policies.residual_checkpoint import is_residual_training_zip, load_residual_training_zip
from hingelab.policies.sb3_zip import is_sac_zip, load_sac_zip, read_plain_data
from hingelab.tasks import HIGH_LEVEL_ACTION_SHAPE as ACTION_SHAPE
from hingelab.tasks import observation_dim

SHIPPED_HIGH_LEVEL = ASSETS_DIR / "checkpoints" / "high_level.zip"


def low_level_sha256(spec: str) -> str:
    """"privileged" or "none", or the sha256 of the low-level checkpoint file (a manifest's own bytes
    name its experts' sha256s, so the manifest's hash covers them)."""
    path = resolve_low_level(spec) if spec != "none" else "none"
    return path if isinstance(path, str) else file_sha256(path)


def training_context(low_level: str) -> dict:
    """What a high-level checkpoint records about the parts it learned beside."""
    return {"low_level": str(low_level), "low_level_sha256": low_level_sha256(str(low_level)),
            "encoder_fingerprint": shipped_encoder_fingerprint()}


def check_context(model, path, low_level: str) -> None:
    """Refuse ``model`` (loaded from ``path``) for use over ``low_level`` if it learned beside another
    low level or encoder (checkpoints without the record are not checked)."""
    provenance = getattr(model, "hingelab_provenance", None) or {}
    trained_sha = provenance.get("low_level_sha256")
    # the privileged low level (the hinge servo reaching every goal) is accepted under any policy: it is
    # the ideal low level that separates the two levels' shares of the failures
    if trained_sha is not None and str(low_level) != "privileged":
        here = low_level_sha256(str(low_level))
        if here != trained_sha:
            raise ConfigError(f"{path} learned over the low level {provenance.get('low_level')} (sha256 "
                              f"{trained_sha[:12]}), not over {low_level} ({here[:12]}); evaluate it with "
                              f"--low-level {provenance.get('low_level')} or train one over this low level")
    trained_encoder = provenance.get("encoder_fingerprint")
    if trained_encoder is not None:
        if not shipped_encoder().accepts(trained_encoder):
            raise ConfigError(f"{path} learned from the latents of another tool encoder (fingerprint "
                              f"{trained_encoder}); retrain it with `hingelab train high` on this encoder")


def resolve_checkpoint(path) -> Path:
    """A zip file, or a folder holding ``model.zip`` (a run folder): the zip to load."""
    path = Path(path)
    if path.is_dir() and (path / "model.zip").is_file():
        path = path / "model.zip"
    if not path.is_file():
        raise ConfigError(f"no high-level checkpoint at {path}; give a stable-baselines3 SAC zip trained on "
                          "ToolPick-v0 (or use --baseline heuristic|scripted|random)")
    return path


def observes_extent(model) -> bool:
    """The checkpoint was trained observing the object's extent (its ``env_kwargs``: 17-D observations)."""
    kwargs = (getattr(model, "hingelab_provenance", None) or {}).get("env_kwargs") or {}
    return bool(kwargs.get("observe_extent", False))


def trained_tool_position(model) -> str:
    """The tool position the checkpoint was trained observing (its ``env_kwargs``; ToolPick-v0's default
    "observed" where it says none)."""
    kwargs = (getattr(model, "hingelab_provenance", None) or {}).get("env_kwargs") or {}
    return str(kwargs.get("tool_position", "observed"))


def observation_form(model) -> dict:
    """ToolPick-v0's arguments that make its observation the one the checkpoint was trained on."""
    return {"observe_extent": observes_extent(model), "tool_position": trained_tool_position(model)}


def load_high_level_checkpoint(path, low_level: str | None = None):
    """A SAC zip trained on ToolPick-v0 (14-D observation, 17-D with ``observe_extent``; 5-D action), or a
    phase clone (``phase_clone.PhaseClone``, a policy with memory: drive it with ``state``, as
    ``hingelab.policies.ModelPolicy`` does), loaded on the CPU; with ``low_level``, checked against the
    low level and encoder it learned beside."""
    path = resolve_checkpoint(path)
    residual = is_residual_policy(path)  # train high --learner residual-sac: a phase clone and a residual
    training_zip = not residual and is_residual_training_zip(path)  # that learner's checkpoints/step_N
    if residual or training_zip or is_phase_clone(path):  # a phase clone (--learner phase-clone): a policy with memory
        model = (ResidualPolicy.load(path) if residual else load_residual_training_zip(path) if training_zip
                 else PhaseClone.load(path))
        env_kwargs = model.hingelab_provenance.get("env_kwargs") or {}
        expected = observation_dim(bool(env_kwargs.get("observe_extent", False)))
        if model.observation_dim != expected:
            raise ConfigError(f"{path} takes {model.observation_dim}-D observations, but the env arguments it "
                              f"records give ToolPick-v0 {expected}-D ones; give a checkpoint trained on "
                              "hingelab/ToolPick-v0")
        if low_level is not None:
            check_context(model, path, low_level)
        return model
    plain, described = read_plain_data(path)
    env_kwargs = (plain.get("hingelab_provenance") or {}).get("env_kwargs") or {}
    expected = (observation_dim(bool(env_kwargs.get("observe_extent", False))),)
    observation = gym.spaces.Box(-np.inf, np.inf, expected, np.float64)
    try:
        model = load_sac_zip(path, observation, gym.spaces.Box(-1.0, 1.0, ACTION_SHAPE, np.float32))
    except ConfigError as exc:
        if "do not fit" not in str(exc):
            raise
        recorded = {k: (described.get(k) or {}).get("_shape") for k in ("observation_space", "action_space")}
        raise ConfigError(f"{path} does not match ToolPick-v0 (observation {recorded['observation_space']}, action "
                          f"{recorded['action_space']}; ToolPick-v0 has observation {expected}, action "
                          f"{ACTION_SHAPE}); give a high-level checkpoint trained on hingelab/ToolPick-v0") from exc
    if low_level is not None:
        check_context(model, path, low_level)
    return model


def _load_phase_clone(path, encoder=None, low_level=None, level=None):
    if level == "low":
        raise ConfigError(f"{path} is a high-level policy (a phase clone or a residual over one); give a "
                          "low-level checkpoint")
    return load_high_level_checkpoint(path, low_level=low_level)


def _load_sac_zip(path, encoder=None, low_level=None, level=None):
    """A SAC zip of either level: ToolShape-v0's (a Dict observation) or ToolPick-v0's; with ``level``, checked
    against that level's task."""
    _, described = read_plain_data(path)
    if level == "low" or (level is None and (described.get("observation_space") or {}).get("spaces")):
        return load_sac_checkpoint(path, encoder)
    return load_high_level_checkpoint(path, low_level=low_level)


register_policy_format("hingelab phase clone", is_phase_clone, _load_phase_clone)
register_policy_format("hingelab residual policy", is_residual_policy, _load_phase_clone)
register_policy_format("residual-sac training checkpoint", is_residual_training_zip, _load_phase_clone)
register_policy_format("stable-baselines3 SAC zip", is_sac_zip, _load_sac_zip)

__all__ = ["load_high_level_checkpoint", "resolve_checkpoint", "training_context", "check_context",
           "low_level_sha256", "observes_extent", "trained_tool_position", "observation_form", "ACTION_SHAPE",
           "SHIPPED_HIGH_LEVEL"]
