"""Loading a stable-baselines3 SAC zip without running any code from it.

``SAC.load`` unpickles the cloudpickle entries of the zip's ``data`` (the policy class, the spaces,
the schedules, the replay-buffer class): a checkpoint from someone else could execute anything on
load. Here those entries are never unpickled. The platform knows what it loads: the caller gives
the observation and action spaces of the env the policy acts in (ToolShape-v0's, ToolPick-v0's);
the policy is SB3's SAC policy for that space (``MlpPolicy``, ``MultiInputPolicy`` for a Dict); its
net sizes, activation and optimizer options, and the run's plain settings and counters, are read
from the plain JSON beside the pickles (strings parsed with ``ast.literal_eval``, which evaluates
literals only); the tensors come from the ``.pth`` entries through ``torch.load(weights_only=True)``.
A zip whose tensors do not fit the nets that describes is refused with a one-line ``ConfigError``.

For inference (evaluations, the frozen low level, the demo): the loaded model has a one-slot
replay buffer and the run's optimizer states; a run's ``--resume`` builds its model from the run's
config and gives it the checkpoint's tensors (``set_weights_from_zip``, ``checkpoints.load_checkpoint``).
"""

from __future__ import annotations

import ast
import io
import json
import re
import zipfile
from pathlib import Path

import torch as th
from gymnasium import spaces
from stable_baselines3 import SAC
from stable_baselines3.common.save_util import recursive_setattr
from stable_baselines3.common.type_aliases import TrainFreq, TrainFrequencyUnit
from stable_baselines3.common.utils import ConstantSchedule, FloatSchedule

from hingelab.errors import ConfigError
from hingelab.seeds import preserved_global_rngs

ACTIVATIONS = {name: getattr(th.nn, name) for name in ("ReLU", "Tanh", "ELU", "LeakyReLU", "SiLU", "GELU")}
# settings the loader rebuilds itself, or that only a training run uses; never taken from the file
REBUILT = frozenset({"policy_class", "policy_kwargs", "observation_space", "action_space", "lr_schedule",
                     "train_freq", "replay_buffer_class", "replay_buffer_kwargs", "buffer_size", "speedups",
                     "_last_obs", "_last_episode_starts", "_last_original_obs", "ep_info_buffer",
                     "ep_success_buffer", "n_envs", "device", "env", "_vec_normalize_env"})


def _is_pickled(value) -> bool:
    return isinstance(value, dict) and ":serialized:" in value


def _literal(value):
    """A plain value; SB3 writes some as their repr strings (``'[256, 256]'``, ``'False'``)."""
    if isinstance(value, str):
        try:
            return ast.literal_eval(value)
        except (ValueError, SyntaxError):
            return value
    return value


def read_plain_data(path) -> tuple[dict, dict]:
    """(plain, described) of the zip's ``data``: its JSON values, and for each pickled entry only the
    readable fields SB3 wrote beside the pickle (its ``:type:`` under "type"). Nothing is executed."""
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, zipfile.BadZipFile, json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path} is not a stable-baselines3 checkpoint ({type(exc).__name__}: {exc})") from exc
    if not isinstance(data, dict):
        raise ConfigError(f"{path} is not a stable-baselines3 checkpoint (its data is not a JSON object)")
    plain = {key: value for key, value in data.items() if not _is_pickled(value)}
    described = {key: {"type": value.get(":type:"), **{k: v for k, v in value.items() if not k.startswith(":")}}
                 for key, value in data.items() if _is_pickled(value)}
    return plain, described


def _policy_kwargs(path: Path, plain: dict, described: dict) -> dict:
    # JSON-able options are stored plain; with a class among them (activation_fn) SB3 pickles the dict
    described = plain.get("policy_kwargs") or {k: v for k, v in (described.get("policy_kwargs") or {}).items()
                                                if k != "type"}
    kwargs = {}
    if "net_arch" in described:
        kwargs["net_arch"] = _literal(described["net_arch"])
    if "activation_fn" in described:
        found = re.search(r"torch\.nn\.modules\.activation\.(\w+)'", str(described["activation_fn"]))
        if found is None or found.group(1) not in ACTIVATIONS:
            raise ConfigError(f"{path}: unknown activation {described['activation_fn']!r}; this loader knows "
                              + ", ".join(ACTIVATIONS))
        kwargs["activation_fn"] = ACTIVATIONS[found.group(1)]
    for key in ("optimizer_kwargs", "use_sde", "log_std_init", "n_critics", "share_features_extractor"):
        if key in described:
            kwargs[key] = _literal(described[key])
    unknown = set(described) - {"net_arch", "activation_fn", "optimizer_kwargs", "use_sde", "log_std_init",
                                "n_critics", "share_features_extractor"}
    if unknown:
        raise ConfigError(f"{path}: policy options this loader does not know ({', '.join(sorted(unknown))})")
    return kwargs


def _learning_rate(plain: dict, described: dict) -> float:
    if isinstance(plain.get("learning_rate"), (int, float)):
        return float(plain["learning_rate"])
    schedule = str((described.get("lr_schedule") or {}).get("value_schedule", ""))
    found = re.search(r"val=([-+0-9.eE]+)", schedule)
    return float(found.group(1)) if found else 3e-4


def load_sac_zip_safely(path, observation_space, action_space, device: str = "cpu"):
    """A SAC model with the zip's weights for these spaces; nothing of the zip is unpickled."""

    path = Path(path)
    plain, described = read_plain_data(path)
    kind = "MultiInputPolicy" if isinstance(observation_space, spaces.Dict) else "MlpPolicy"
    model = SAC(kind, env=None, device=device, _init_setup_model=False)
    model.__dict__.update({k: v for k, v in plain.items() if k not in REBUILT})
    model.observation_space, model.action_space = observation_space, action_space
    model.policy_kwargs = _policy_kwargs(path, plain, described)
    model.learning_rate = _learning_rate(plain, described)
    model.lr_schedule = FloatSchedule(ConstantSchedule(model.learning_rate))
    model.train_freq = TrainFreq(1, TrainFrequencyUnit.STEP)
    model.buffer_size, model.replay_buffer_class, model.replay_buffer_kwargs, model.n_envs = 1, None, {}, 1
    with preserved_global_rngs():  # SB3 reseeds the global generators with the zip's seed; the weights are the zip's
        model._setup_model()
    set_weights_from_zip(model, path, device=device)
    return model


def set_weights_from_zip(model, path, device: str = "cpu") -> None:
    """Give ``model`` the zip's tensors (policy, optimizers, entropy coefficient), read with
    ``torch.load(weights_only=True)``; tensors that do not fit its nets are a one-line ConfigError."""

    path = Path(path)
    try:
        with zipfile.ZipFile(path) as archive:
            tensors = {name[:-len(".pth")]: th.load(io.BytesIO(archive.read(name)), map_location=device,
                                                    weights_only=True)
                       for name in archive.namelist() if name.endswith(".pth")}
    except Exception as exc:  # noqa: BLE001 - a refused pickle, a bad zip: one line
        raise ConfigError(f"{path}: its tensors do not load as plain weights ({type(exc).__name__}: "
                          f"{str(exc).splitlines()[0] if str(exc) else ''}); it is refused unread") from exc
    variables = tensors.pop("pytorch_variables", None) or {}
    try:
        model.set_parameters(tensors, exact_match=True, device=device)
    except Exception as exc:  # noqa: BLE001 - shapes or names that do not fit
        raise ConfigError(f"{path}: its weights do not fit a SAC policy for observation {model.observation_space} "
                          f"and action {model.action_space} ({type(exc).__name__}); give a checkpoint of this env "
                          "(or, resuming, the config the run was started with)") from exc
    for name, value in variables.items():
        if value is not None:
            recursive_setattr(model, f"{name}.data", value.data)


def load_sac_zip(path, observation_space, action_space):
    """A stable-baselines3 SAC zip for these spaces, loaded on the CPU without unpickling anything of it;
    a file that is not one, or does not fit them, is a one-line ConfigError."""
    if not Path(path).is_file():
        raise ConfigError(f"{path} does not exist; give a SAC checkpoint (.zip)")
    return load_sac_zip_safely(path, observation_space, action_space, device="cpu")


def is_sac_zip(path) -> bool:
    """A stable-baselines3 zip: its ``data`` and ``policy.pth`` entries."""
    try:
        with zipfile.ZipFile(path) as archive:
            names = set(archive.namelist())
    except (OSError, zipfile.BadZipFile):
        return False
    return {"data", "policy.pth"} <= names


__all__ = ["load_sac_zip", "load_sac_zip_safely", "read_plain_data", "set_weights_from_zip", "is_sac_zip"]
