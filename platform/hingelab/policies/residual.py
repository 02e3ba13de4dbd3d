"""A residual high-level policy: a bounded correction learned over a frozen base policy with memory.

Why: SAC trained from the privileged buffer wore the cloned policy down (``analysis/high-level/``): from
its first update the actor moved away from the clone on the say of an untrained critic, and its
exploration shook the tool out of the hand. A residual policy (Policy Decorator, Yuan et al. 2024;
residual RL, Johannink et al. 2019) keeps the clone as a frozen base and learns only a correction of at
most ``scale`` per action dimension on top of it:

    a = clip(a_base(o, m) + scale * tanh(mu(x)), -1, 1)

where ``a_base`` is the base's action for the observation ``o`` and its memory ``m`` (the phase clone's
phase and steps in it), and ``x`` is the residual's input (``residual_inputs``): the observation
standardized by the base's own statistics, with the tool's Euler angles (which flip near +-pi from one
episode to the next) replaced by the first two columns of the rotation matrix, the base's memory (phase
one-hot, steps / 60) and the base's action. The residual's last layer starts at zero, so the policy at
step 0 *is* its base, and whatever it learns it stays within ``scale`` of it.

A policy trained with ``--choose-by-q`` (IBRL, Hu et al. 2023: the base proposes too) also carries the
learner's critics, and at every step acts with the residual only where their pessimistic value (the minimum
over the members) of ``base + residual`` beats that of the base's own action; elsewhere it acts as its base.

``ResidualPolicy.predict(observation, state, episode_start, deterministic)`` returns ``(action, state)``
with the base's memory as state, so ``hingelab.policies.ModelPolicy`` drives it as it drives the phase
clone. A checkpoint is a zip of ``residual.json`` (layout, scale, provenance), ``base.zip`` (the base's
own checkpoint, bytes unchanged), ``actor.npz`` and, for a policy that chooses by Q, ``critic.npz`` (plain
arrays): loading unpickles nothing.
"""

from __future__ import annotations

import hashlib
import io
import json
import math
import zipfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

from hingelab.errors import ConfigError
from hingelab.json_text import finite_or_null, strict_dumps
from hingelab.policies.phase_clone import (
    ACTION_DIM,
    MAX_PHASE_STEPS,
    PHASES,
    PhaseClone,
    batch_with_memory,
    is_phase_clone,
)
from hingelab.seeds import preserved_global_rngs

META_FILE, BASE_FILE, ACTOR_FILE, CRITIC_FILE = "residual.json", "base.zip", "actor.npz", "critic.npz"
FORMAT = "hingelab residual policy 1"
FORMAT_CHOOSING = "hingelab residual policy 2"  # with critic.npz: chooses between base and residual by Q
EULER = slice(3, 6)  # ToolPick-v0's observation: the tool's Euler angles (xyz, rad)
MIN_STD = 1e-3  # observation dimensions the base saw (nearly) constant are scaled by this, not by ~0


def check_scale(scale) -> np.ndarray:
    """The residual's scale per action dimension, each in (0, 1]; one number is every dimension's."""
    values = np.atleast_1d(np.asarray(scale, np.float64))
    if values.ndim != 1 or len(values) not in (1, ACTION_DIM):
        raise ConfigError(f"the residual scale is one number or {ACTION_DIM} (latent goal 0 and 1, hand velocity x, "
                          f"y, z), not {values.tolist()}")
    values = np.broadcast_to(values, (ACTION_DIM,)).copy()
    if not (np.isfinite(values).all() and (values > 0).all() and (values <= 1).all()):
        raise ConfigError(f"the residual scale is the largest correction of an action dimension, in (0, 1]; "
                          f"got {np.asarray(scale).tolist()}")
    return values


def euler_xyz_to_6d(euler: np.ndarray) -> np.ndarray:
    """(n, 3) Euler angles xyz (extrinsic, as the env reports them) -> (n, 6): the rotation matrix's first two
    columns, continuous in the rotation (Zhou et al. 2019)."""
    x, y, z = (euler[:, i] for i in range(3))
    cx, sx, cy, sy, cz, sz = np.cos(x), np.sin(x), np.cos(y), np.sin(y), np.cos(z), np.sin(z)
    # R = Rz Ry Rx; columns 0 and 1
    col0 = np.stack([cz * cy, sz * cy, -sy], axis=1)
    col1 = np.stack([cz * sy * sx - sz * cx, sz * sy * sx + cz * cx, cy * sx], axis=1)
    return np.concatenate([col0, col1], axis=1)


class ResidualInputs:
    """The residual's input from the observation, the base's memory and the base's action (module doc)."""

    def __init__(self, mean: np.ndarray, std: np.ndarray):
        keep = np.ones(len(mean), bool)
        keep[EULER] = False
        self.keep = keep
        self.mean = np.asarray(mean, np.float64)[keep]
        self.std = np.maximum(np.asarray(std, np.float64)[keep], MIN_STD)
        self.observation_dim = len(mean)
        self.dim = int(keep.sum()) + 6 + len(PHASES) + 1 + ACTION_DIM

    @classmethod
    def of_base(cls, base: PhaseClone) -> "ResidualInputs":
        net = base.nets[0]
        return cls(net.mean.numpy(), net.std.numpy())

    def __call__(self, obs: np.ndarray, memory: np.ndarray, base_action: np.ndarray) -> np.ndarray:
        obs = np.asarray(obs, np.float64).reshape(-1, self.observation_dim)
        memory = np.asarray(memory, np.int64).reshape(-1, 2)
        phase = np.eye(len(PHASES))[memory[:, 0]]
        steps = np.minimum(memory[:, 1], MAX_PHASE_STEPS)[:, None] / MAX_PHASE_STEPS
        parts = [(obs[:, self.keep] - self.mean) / self.std, euler_xyz_to_6d(obs[:, EULER]), phase, steps,
                 np.asarray(base_action, np.float64).reshape(-1, ACTION_DIM)]
        return np.concatenate(parts, axis=1).astype(np.float32)

    @staticmethod
    def base_action(x):
        """The base's action inside a batch of inputs (its last ``ACTION_DIM`` columns; numpy or torch)."""
        return x[:, -ACTION_DIM:]


def compose(base_action, residual, scale):
    """The executed action: clip(base + scale * residual, -1, 1) (torch tensors or numpy arrays)."""
    if isinstance(base_action, torch.Tensor):
        return torch.clamp(base_action + scale * residual, -1.0, 1.0)
    return np.clip(base_action + scale * residual, -1.0, 1.0)


def actor_mlp(input_dim: int, hidden: tuple[int, ...]) -> nn.Sequential:
    """The residual's deterministic actor: Linear/ReLU layers, then the mean layer (tanh applied by the caller)."""
    layers, width = [], input_dim
    for h in hidden:
        layers += [nn.Linear(width, h), nn.ReLU()]
        width = h
    layers.append(nn.Linear(width, ACTION_DIM))
    return nn.Sequential(*layers)


class EnsembleLinear(nn.Module):
    """``members`` independent Linear layers applied to ``(members, batch, in)`` in one ``baddbmm``."""

    def __init__(self, members: int, in_features: int, out_features: int):
        super().__init__()
        self.weight = nn.Parameter(torch.empty(members, in_features, out_features))
        self.bias = nn.Parameter(torch.empty(members, 1, out_features))
        bound = 1.0 / math.sqrt(in_features)  # nn.Linear's default initialization, per member
        nn.init.uniform_(self.weight, -bound, bound)
        nn.init.uniform_(self.bias, -bound, bound)

    def forward(self, x: torch.Tensor, members: torch.Tensor | None = None) -> torch.Tensor:
        """``x`` (members or len(members), batch, in); ``members``: the indices of the members to apply."""
        if members is None:
            return torch.baddbmm(self.bias, x, self.weight)
        return torch.baddbmm(self.bias.index_select(0, members), x, self.weight.index_select(0, members))


def ensemble_q_net(members: int, input_dim: int, hidden: tuple[int, ...], layer_norm: bool) -> nn.Sequential:
    """The critics' layers (``input_dim``: the residual's input and the executed action): EnsembleLinear, then
    LayerNorm over each member's features where ``layer_norm``, then ReLU, per hidden layer; then Q."""
    widths = [int(input_dim), *[int(n) for n in hidden]]
    layers: list[nn.Module] = []
    for w_in, w_out in zip(widths, widths[1:]):
        layers.append(EnsembleLinear(members, w_in, w_out))
        if layer_norm:
            layers.append(nn.LayerNorm(w_out))  # over the last axis: each member's features
        layers.append(nn.ReLU())
    layers.append(EnsembleLinear(members, widths[-1], 1))
    return nn.Sequential(*layers)


def ensemble_q_values(q_net: nn.Sequential, features: torch.Tensor, executed: torch.Tensor, members: int,
                      chosen: torch.Tensor | None = None) -> torch.Tensor:
    """(members or len(chosen), batch, 1): each member's Q of (``features``, ``executed`` action)."""
    x = torch.cat([features, executed], dim=1)
    h = x.unsqueeze(0).expand(members if chosen is None else len(chosen), -1, -1)
    for layer in q_net:
        h = layer(h, chosen) if isinstance(layer, EnsembleLinear) else layer(h)
    return h


class ChooseByQ:
    """Acts with the residual only where the critics' minimum Q of ``base + residual`` exceeds their minimum Q
    of the base's own action (IBRL's choice between the proposals, module doc)."""

    def __init__(self, q_net: nn.Sequential, members: int, scale):
        self.q_net, self.members = q_net, int(members)
        self.scale = torch.as_tensor(np.asarray(scale, np.float32))

    def wins(self, x: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        """(batch,) bool: where the residual's action is worth more than the base's."""
        base = ResidualInputs.base_action(x)
        with torch.no_grad():
            q_residual = ensemble_q_values(self.q_net, x, compose(base, residual, self.scale), self.members)
            q_base = ensemble_q_values(self.q_net, x, compose(base, torch.zeros_like(residual), self.scale),
                                       self.members)
        return q_residual.min(dim=0).values[:, 0] > q_base.min(dim=0).values[:, 0]

    def __call__(self, x: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        return torch.where(self.wins(x, residual)[:, None], residual, torch.zeros_like(residual))


class ResidualPolicy:
    """Base + bounded residual (module doc); ``actor`` maps a batch of inputs to residuals in [-1, 1];
    ``chooser`` (optional, ``ChooseByQ``) keeps the residual only where the critics prefer it."""

    def __init__(self, base: PhaseClone, actor, scale, provenance: dict | None = None, base_bytes: bytes = b"",
                 chooser: ChooseByQ | None = None):
        self.base, self.actor, self.chooser = base, actor, chooser
        self.scale = check_scale(scale)
        self.inputs = ResidualInputs.of_base(base)
        self.hingelab_provenance = provenance or {}
        self.base_bytes = base_bytes

    @property
    def observation_dim(self) -> int:
        return self.base.observation_dim

    def step(self, obs: np.ndarray, memory: np.ndarray):
        """(the residual's inputs, the base's action, the base's next memory) for a batch."""
        base_action, next_memory = self.base.predict(obs, memory)
        return self.inputs(obs, memory, base_action), base_action, next_memory

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        obs, single, memory = batch_with_memory(observation, state, episode_start, self.observation_dim)
        x, base_action, next_memory = self.step(obs, memory)
        with torch.no_grad():
            inputs = torch.as_tensor(x)
            residual = self.actor(inputs)
            if self.chooser is not None:
                residual = self.chooser(inputs, residual)
        action = compose(base_action, residual.numpy(), self.scale).astype(np.float32)
        return (action[0] if single else action), next_memory

    # ------------------------------------------------------------------ files
    def save(self, path, actor_state: dict[str, torch.Tensor], hidden: tuple[int, ...],
             critic: dict | None = None) -> None:
        """Write the checkpoint; ``actor_state`` holds the actor MLP's weights (``actor_mlp``'s names);
        ``critic`` (a policy that chooses by Q): ``{"state": the q_net's state dict, "members": E, "hidden":
        [...], "layer_norm": bool}``."""
        path = Path(path)
        meta = {"format": FORMAT, "observation_dim": self.observation_dim, "input_dim": self.inputs.dim,
                "hidden": list(hidden), "scale": self.scale.tolist(),
                "base_sha256": hashlib.sha256(self.base_bytes).hexdigest(),
                "hingelab_provenance": self.hingelab_provenance}
        if critic is not None:
            meta["format"] = FORMAT_CHOOSING
            meta["critic"] = {"members": int(critic["members"]), "hidden": [int(n) for n in critic["hidden"]],
                              "layer_norm": bool(critic["layer_norm"])}
        tmp = path.with_name(path.name + ".tmp")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(META_FILE, strict_dumps(finite_or_null(meta), path, indent=1, default=str))
            archive.writestr(BASE_FILE, self.base_bytes)
            archive.writestr(ACTOR_FILE, _npz(actor_state))
            if critic is not None:
                archive.writestr(CRITIC_FILE, _npz(critic["state"]))
        tmp.replace(path)  # a crash mid-write leaves the previous file

    @classmethod
    def load(cls, path) -> "ResidualPolicy":
        path = Path(path)
        try:
            with zipfile.ZipFile(path) as archive:
                meta = json.loads(archive.read(META_FILE))
                if meta.get("format") not in (FORMAT, FORMAT_CHOOSING):
                    raise ConfigError(f"{path} is a residual policy of another layout ({meta.get('format')}); this "
                                      f"hingelab reads {FORMAT!r} and {FORMAT_CHOOSING!r}")
                base_bytes = archive.read(BASE_FILE)
                state = _tensors(archive.read(ACTOR_FILE))
                critic_state = _tensors(archive.read(CRITIC_FILE)) if meta["format"] == FORMAT_CHOOSING else None
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ConfigError(f"{path} is not a readable residual-policy checkpoint ({type(exc).__name__}: {exc}); "
                              "train one with `hingelab train high --learner residual-sac`") from exc
        if hashlib.sha256(base_bytes).hexdigest() != meta.get("base_sha256"):
            raise ConfigError(f"{path}: its base policy does not match the sha256 it records; the file is damaged")
        base = load_base(io.BytesIO(base_bytes), where=f"{path}'s base")
        actor = loaded_actor(state, int(meta["input_dim"]), tuple(meta["hidden"]), where=str(path))
        chooser = None
        if critic_state is not None:
            layout = meta["critic"]
            chooser = loaded_chooser(critic_state, layout["members"], int(meta["input_dim"]) + ACTION_DIM,
                                     tuple(layout["hidden"]), layout["layer_norm"], meta["scale"], where=str(path))
        return cls(base, actor, meta["scale"], meta.get("hingelab_provenance") or {}, base_bytes, chooser)


def loaded_actor(state: dict[str, torch.Tensor], input_dim: int, hidden: tuple[int, ...], where: str):
    """The squashed deterministic actor of ``actor_mlp``'s layout with ``state``'s weights; a one-line error
    naming ``where`` when they do not fit."""
    with preserved_global_rngs():  # the initial weights are overwritten: loading draws nothing
        actor = actor_mlp(input_dim, hidden)
    try:
        actor.load_state_dict(state)
    except RuntimeError as exc:
        raise ConfigError(f"{where}: its actor weights do not fit a residual actor of layers {hidden} ({exc})") from exc
    actor.eval()
    return _squashed(actor)


def loaded_chooser(state: dict[str, torch.Tensor], members: int, input_dim: int, hidden: tuple[int, ...],
                   layer_norm: bool, scale, where: str) -> "ChooseByQ":
    """``ChooseByQ`` over an ``ensemble_q_net`` with ``state``'s weights; a one-line error naming ``where``."""
    with preserved_global_rngs():
        q_net = ensemble_q_net(members, input_dim, hidden, layer_norm)
    try:
        q_net.load_state_dict(state)
    except RuntimeError as exc:
        raise ConfigError(f"{where}: its critic weights do not fit critics of layers {hidden} ({exc})") from exc
    q_net.eval()
    return ChooseByQ(q_net, members, scale)


def _squashed(mlp: nn.Module):
    return lambda x: torch.tanh(mlp(x))


def _npz(state: dict[str, torch.Tensor]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **{k: v.detach().cpu().numpy() for k, v in state.items()})
    return buffer.getvalue()


def _tensors(npz_bytes: bytes) -> dict[str, torch.Tensor]:
    arrays = np.load(io.BytesIO(npz_bytes), allow_pickle=False)
    return {k: torch.as_tensor(arrays[k]) for k in arrays.files}


def load_base(source, where: str = "") -> PhaseClone:
    """The base policy: a phase-clone checkpoint (a path or a file object); a one-line error otherwise."""
    if isinstance(source, (str, Path)) and not is_phase_clone(source):
        raise ConfigError(f"{source} is not a phase-clone checkpoint; the residual learner's base is a phase clone "
                          "(`hingelab train high --learner phase-clone`, or the shipped assets/checkpoints/"
                          "high_level.zip)")
    try:
        return PhaseClone.load(source)
    except ConfigError as exc:
        raise ConfigError(f"{where or source}: {exc}") from exc


def is_residual_policy(path) -> bool:
    try:
        with zipfile.ZipFile(path) as archive:
            return META_FILE in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


__all__ = ["ResidualPolicy", "ResidualInputs", "ChooseByQ", "EnsembleLinear", "compose", "actor_mlp", "check_scale",
           "loaded_actor", "loaded_chooser",
           "ensemble_q_net", "ensemble_q_values", "load_base", "euler_xyz_to_6d", "is_residual_policy", "FORMAT",
           "FORMAT_CHOOSING"]
