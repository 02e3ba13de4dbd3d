"""A residual learner's training checkpoint as a policy: ``hingelab eval high RUNDIR/checkpoints/step_N``.

A run of ``train high --learner residual-sac`` writes its policy file (``policies.residual``'s format) only
at evaluations and at the end (``best_model.zip``, ``model.zip``); its checkpoints hold stable-baselines3's
training zip, whose policy class (``ResidualSACPolicy``) no plain loader can build. This reads that zip's
tensors (``torch.load(weights_only=True)``: nothing is unpickled) and the run folder's ``config.json`` (the
base clone, checked against the sha256 the run recorded; whether the policy chooses by Q) and gives the
``ResidualPolicy`` the run would have saved at that step, so a curve's dip can be evaluated on other seeds.
"""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from pathlib import Path

import torch

from hingelab.errors import ConfigError
from hingelab.policies.residual import ResidualPolicy, load_base, loaded_actor, loaded_chooser
from hingelab.policies.sb3_zip import read_plain_data

POLICY_CLASS = "ResidualSACPolicy"


def is_residual_training_zip(path) -> bool:
    """An SB3 zip whose policy class is the residual learner's (its ``data`` names it; nothing is unpickled)."""
    try:
        with zipfile.ZipFile(path) as archive:
            if "policy.pth" not in archive.namelist():
                return False
            data = json.loads(archive.read("data"))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return False
    policy_class = data.get("policy_class") if isinstance(data, dict) else None
    # SB3 writes a class's readable attributes beside its pickle: the __init__'s repr names the class
    return isinstance(policy_class, dict) and f"{POLICY_CLASS}.__init__" in str(policy_class.get("__init__", ""))


def run_folder_of(path: Path) -> Path:
    """RUNDIR of ``RUNDIR/checkpoints/step_N/model.zip``; a one-line error for a zip anywhere else."""
    path = Path(path).resolve()
    run_dir = path.parent.parent.parent
    if path.parent.parent.name != "checkpoints" or not (run_dir / "config.json").is_file():
        raise ConfigError(f"{path} is a residual-sac training zip outside its run folder; it loads from "
                          "RUNDIR/checkpoints/step_N (the base and settings are in RUNDIR/config.json), or give "
                          "the run's policy file RUNDIR/model.zip or best_model.zip")
    return run_dir


def _base_bytes(run_dir: Path, doc: dict) -> bytes:
    record = doc.get("base") or {}
    base = Path(record.get("path", ""))
    # the recorded path may be another worktree's or relative to where the run started: try the run's own copy
    candidates = [run_dir / "base.zip", base, Path.cwd() / base]
    for candidate in candidates:
        if candidate.is_file():
            data = candidate.read_bytes()
            if record.get("sha256") in (None, _sha256(data)):
                return data
    raise ConfigError(f"{run_dir}/config.json: the run's base clone ({record.get('path')}, sha256 "
                      f"{str(record.get('sha256'))[:12]}...) is not found unchanged; put that file back to "
                      "evaluate this checkpoint")


def _sha256(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def load_residual_training_zip(path) -> ResidualPolicy:
    path = Path(path)
    run_dir = run_folder_of(path)
    doc = json.loads((run_dir / "config.json").read_text())
    config = doc.get("config", {})
    plain, described = read_plain_data(path)
    kwargs = plain.get("policy_kwargs") or described.get("policy_kwargs") or {}
    try:
        scale = json.loads(str(kwargs["residual_scale"]))
        hidden = tuple(json.loads(str(kwargs["net_arch"])))
    except (KeyError, ValueError) as exc:
        raise ConfigError(f"{path}: its policy options do not name the residual scale and layers ({exc})") from exc
    try:
        with zipfile.ZipFile(path) as archive:
            tensors = torch.load(io.BytesIO(archive.read("policy.pth")), map_location="cpu", weights_only=True)
    except Exception as exc:  # noqa: BLE001 - a refused pickle, a bad zip: one line
        raise ConfigError(f"{path}: its tensors do not load as plain weights ({type(exc).__name__})") from exc
    linears = sorted({int(k.split(".")[2]) for k in tensors if k.startswith("actor.latent_pi.")})
    state = {}
    for i, index in enumerate(linears):
        for part in ("weight", "bias"):
            state[f"{2 * i}.{part}"] = tensors[f"actor.latent_pi.{index}.{part}"]
    for part in ("weight", "bias"):
        state[f"{2 * len(linears)}.{part}"] = tensors[f"actor.mu.{part}"]
    base_bytes = _base_bytes(run_dir, doc)
    base = load_base(io.BytesIO(base_bytes), where=f"{run_dir}'s base")
    actor = loaded_actor(state, int(state["0.weight"].shape[1]), hidden, where=str(path))
    chooser = None
    if config.get("choose_by_q"):
        q_state = {k[len("critic.q_net."):]: v for k, v in tensors.items() if k.startswith("critic.q_net.")}
        weights = [q_state[k] for k in sorted((k for k in q_state if k.endswith(".weight") and q_state[k].dim() == 3),
                                              key=lambda k: int(k.split(".")[0]))]
        chooser = loaded_chooser(q_state, int(weights[0].shape[0]), int(weights[0].shape[1]),
                                 tuple(int(w.shape[2]) for w in weights[:-1]),
                                 bool(config.get("critic_layer_norm", True)), scale, where=str(path))
    recorded = {k: v for k, v in (plain.get("hingelab_provenance") or {}).items() if k != "evaluation"}
    # env and low-level context as the run records it; the settings as config.json holds them (the zip keeps a repr)
    provenance = {**recorded, "config": config, "checkpoint": str(path.parent)}
    return ResidualPolicy(base, actor, scale, provenance, base_bytes, chooser)


__all__ = ["is_residual_training_zip", "load_residual_training_zip", "run_folder_of"]
