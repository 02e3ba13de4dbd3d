"""The phase clone: a high-level policy cloned from the scripted demonstrator, with its phase as memory.

Why: a Markov network cloned from the scripted high level picks far fewer objects than the scripted
high level itself (``analysis/high-level/README.md``). The scripted decisions depend on the demonstrator's phase and the
steps spent in it (it lines up 3 cm over the grip point before it descends, it closes for a set count of steps before it
lifts), which its observation does not hold: the Markov clone averages the phases where they meet (it descends while
still centimetres off to the side, it never closes all the way). The phase clone is a network of
the observation and its own memory, the phase it is in (one of ``PHASES``, the heuristic's, its
"hold" folded into "carry") and the steps it has spent there; it outputs the action and the next
phase, trained on the demonstrator's phases (recorded with the demos: ``DemonstratorLabels``). At
run time its memory is what it predicted, not the demonstrator's: nothing privileged is read.

``PhaseClone.predict(observation, state, episode_start, deterministic)`` returns ``(action,
state)`` as stable-baselines3's recurrent policies do (``state``: ``(n, 2)`` int, phase and steps;
``None`` or ``episode_start`` starts a new episode in "open"), so ``hingelab.policies.ModelPolicy``
drives it and a SAC zip alike. It may hold several nets (an ensemble, ``hingelab.learners.phase_clone.fit``) that
share one memory. A checkpoint is a zip of ``phase_clone.json`` (layout, provenance) and ``weights.npz``
(plain arrays, each net's observation standardization with its weights: loading unpickles nothing).
"""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path

import numpy as np
import torch
from torch import nn

from hingelab.errors import ConfigError
from hingelab.json_text import finite_or_null, strict_dumps
from hingelab.seeds import preserved_global_rngs

PHASES = ("open", "above", "descend", "close", "carry")  # the heuristic's (hingelab.heuristic.controller)
MAX_PHASE_STEPS = 60  # the steps input saturates here (the heuristic's longest phase timeout)
ACTION_DIM = 5
META_FILE, WEIGHTS_FILE = "phase_clone.json", "weights.npz"
FORMAT = "hingelab phase clone 2"  # one net or an ensemble (weights "MEMBER/name")
FORMAT_ONE = "hingelab phase clone 1"  # one net (read, not written)
LABELS = ("demo_phase", "demo_phase_steps", "demo_next_phase")  # the demos' step infos (DemonstratorLabels)


def phase_index(name: str) -> int:
    """The index in ``PHASES`` of one of the heuristic's phase names ("hold" counts as "carry")."""
    return PHASES.index("carry" if name == "hold" else name)


def next_memory(phase: np.ndarray, steps: np.ndarray, next_phase: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The memory after a step: the predicted phase, and its steps (0 on entering a phase)."""
    return next_phase, np.where(next_phase == phase, steps + 1, 0)


def batch_with_memory(observation, state, episode_start, observation_dim: int):
    """(observations ``(n, D)`` float32, whether one observation came, the memory ``(n, 2)``: ``state``, or
    the start of an episode where it is None or ``episode_start`` says so)."""
    obs = np.asarray(observation, np.float32)
    single = obs.ndim == 1
    obs = obs.reshape(-1, observation_dim)
    n = len(obs)
    memory = np.zeros((n, 2), np.int64) if state is None else np.array(state, np.int64).reshape(n, 2)
    if episode_start is not None:
        memory[np.asarray(episode_start, bool).reshape(n)] = 0
    return obs, single, memory


class PhaseCloneNet(nn.Module):
    """MLP(standardized observation, phase one-hot, steps / MAX_PHASE_STEPS) -> (action in (-1, 1),
    next-phase logits)."""

    def __init__(self, observation_dim: int, hidden: tuple[int, ...], mean: np.ndarray, std: np.ndarray):
        super().__init__()
        self.observation_dim, self.hidden = int(observation_dim), tuple(int(h) for h in hidden)
        self.register_buffer("mean", torch.as_tensor(np.asarray(mean, np.float32)))
        self.register_buffer("std", torch.as_tensor(np.asarray(std, np.float32)))
        layers, width = [], self.observation_dim + len(PHASES) + 1
        for h in self.hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        self.trunk = nn.Sequential(*layers)
        self.action_head = nn.Linear(width, ACTION_DIM)
        self.phase_head = nn.Linear(width, len(PHASES))

    def forward(self, observation, phase, steps):
        x = torch.cat([(observation - self.mean) / self.std, nn.functional.one_hot(phase, len(PHASES)).float(),
                       (steps.float().clamp(max=MAX_PHASE_STEPS) / MAX_PHASE_STEPS)[:, None]], dim=1)
        h = self.trunk(x)
        return torch.tanh(self.action_head(h)), self.phase_head(h)


class PhaseClone:
    """A high-level policy with phase memory (module doc); ``hingelab_provenance`` as a SAC zip's.

    It holds one ``PhaseCloneNet`` or several (an ensemble: ``train high --clone-members``, nets fitted
    on the same demos from different seeds): the action is the members' mean, the next phase the one
    of highest mean probability, so the members share one memory."""

    def __init__(self, nets, provenance: dict | None = None):
        self.nets = [net.eval() for net in ([nets] if isinstance(nets, PhaseCloneNet) else list(nets))]
        if not self.nets or len({net.observation_dim for net in self.nets}) != 1:
            raise ConfigError("a phase clone needs one net or more, all of the same observation size")
        self.hingelab_provenance = provenance or {}

    @property
    def observation_dim(self) -> int:
        return self.nets[0].observation_dim

    def predict(self, observation, state=None, episode_start=None, deterministic: bool = True):
        """(action, state) for one observation ``(D,)`` or a batch ``(n, D)``; see the module doc."""
        obs, single, memory = batch_with_memory(observation, state, episode_start, self.observation_dim)
        inputs = (torch.as_tensor(obs), torch.as_tensor(memory[:, 0]), torch.as_tensor(memory[:, 1]))
        with torch.no_grad():
            outputs = [net(*inputs) for net in self.nets]
            action = torch.stack([a for a, _ in outputs]).mean(0)
            probability = torch.stack([torch.softmax(logits, 1) for _, logits in outputs]).mean(0)
        phase, steps = next_memory(memory[:, 0], memory[:, 1], probability.argmax(1).numpy())
        action = action.numpy().astype(np.float32)
        return (action[0] if single else action), np.stack([phase, steps], axis=1)

    # ------------------------------------------------------------------ files
    def save(self, path) -> None:
        path = Path(path)
        weights = io.BytesIO()
        np.savez(weights, **{f"{i}/{k}": v.detach().cpu().numpy() for i, net in enumerate(self.nets)
                             for k, v in net.state_dict().items()})
        meta = {"format": FORMAT, "observation_dim": self.observation_dim,
                "hidden": [list(net.hidden) for net in self.nets],
                "phases": list(PHASES), "max_phase_steps": MAX_PHASE_STEPS,
                "hingelab_provenance": self.hingelab_provenance}
        tmp = path.with_name(path.name + ".tmp")
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as archive:
            archive.writestr(META_FILE, strict_dumps(finite_or_null(meta), path, indent=1, default=str))
            archive.writestr(WEIGHTS_FILE, weights.getvalue())
        tmp.replace(path)  # a crash mid-write leaves the previous file

    @classmethod
    def load(cls, path) -> "PhaseClone":
        """A clone of this format, or of ``FORMAT_ONE`` (one net: its weights unprefixed, ``hidden`` flat);
        ``path`` may be a file object (a residual policy holds its base inside its own zip)."""
        path = path if hasattr(path, "read") else Path(path)
        try:
            with zipfile.ZipFile(path) as archive:
                meta = json.loads(archive.read(META_FILE))
                if meta.get("format") not in (FORMAT, FORMAT_ONE) or tuple(meta.get("phases", ())) != PHASES:
                    raise ConfigError(f"{path} is a phase clone of another layout ({meta.get('format')}, phases "
                                      f"{meta.get('phases')}); this hingelab reads {FORMAT!r} and {FORMAT_ONE!r} "
                                      f"with phases {PHASES}")
                arrays = np.load(io.BytesIO(archive.read(WEIGHTS_FILE)), allow_pickle=False)
                arrays = {k: torch.as_tensor(arrays[k]) for k in arrays.files}
        except (OSError, KeyError, ValueError, EOFError, zipfile.BadZipFile) as exc:
            raise ConfigError(f"{path} is not a readable phase-clone checkpoint ({type(exc).__name__}: {exc}); "
                              "train one with `hingelab train high --learner phase-clone`") from exc
        if meta["format"] == FORMAT_ONE:
            hidden, states = [meta["hidden"]], [arrays]
        else:
            hidden = meta["hidden"]
            states = [{k.split("/", 1)[1]: v for k, v in arrays.items() if k.split("/", 1)[0] == str(i)}
                      for i in range(len(hidden))]
        nets = []
        for layout, state in zip(hidden, states):
            try:
                with preserved_global_rngs():  # the initial weights are overwritten: loading draws nothing
                    net = PhaseCloneNet(meta["observation_dim"], tuple(layout), state["mean"].numpy(),
                                        state["std"].numpy())
                net.load_state_dict(state)
            except (KeyError, RuntimeError) as exc:
                raise ConfigError(f"{path}: its weights do not fit its own layout "
                                  f"({type(exc).__name__}: {exc})") from exc
            nets.append(net)
        return cls(nets, meta.get("hingelab_provenance") or {})


def net_state(net: PhaseCloneNet) -> dict:
    """A net as plain data (its layout and its weights as NumPy arrays): what a ``--jobs`` worker is sent and
    sends back (``net_from_state``), as a saved clone holds it."""
    return {"observation_dim": net.observation_dim, "hidden": tuple(net.hidden),
            "weights": {k: v.detach().cpu().numpy().copy() for k, v in net.state_dict().items()}}


def net_from_state(state: dict) -> PhaseCloneNet:
    """The net of ``net_state``, in eval mode (as a fitted or loaded one); the global generators untouched."""
    weights = {k: torch.as_tensor(v) for k, v in state["weights"].items()}
    with preserved_global_rngs():  # the initial weights are overwritten: building the net draws nothing
        net = PhaseCloneNet(state["observation_dim"], state["hidden"], weights["mean"].numpy(),
                            weights["std"].numpy())
    net.load_state_dict(weights)
    return net.eval()


def is_phase_clone(path) -> bool:
    """Whether ``path`` is a phase-clone zip (not a stable-baselines3 one)."""
    try:
        with zipfile.ZipFile(path) as archive:
            return META_FILE in archive.namelist()
    except (OSError, zipfile.BadZipFile):
        return False


__all__ = ["PHASES", "LABELS", "ACTION_DIM", "PhaseClone", "PhaseCloneNet", "batch_with_memory", "is_phase_clone",
           "next_memory", "phase_index", "net_state", "net_from_state"]
