"""Resumable checkpoints of a SAC run: model, replay buffer, RNG states and run counters,
in formats that load without running code.

``RUNDIR/checkpoints/step_000010000/`` holds ``model.zip`` (SB3's file; on resume only its
tensors are read, ``torch.load(weights_only=True)``, into a model the run builds from its
config), ``replay_buffer.npz`` (``resume_state.save_buffer``) and ``state.json`` (torch, numpy
and Python RNG states, SB3's step, update and episode counters, the envs' episode counts,
elapsed wall time, evaluation bookkeeping). A checkpoint is written into a temporary folder
and renamed when complete, so a crash or a full disk never leaves a half checkpoint that
looks whole; the newest ``keep`` complete checkpoints are kept. Checkpoints of an older
hingelab (``state.pkl``, ``replay_buffer.pkl``) are refused on resume, unread;
``hingelab checkpoints convert RUNDIR`` rewrites trusted ones (``convert_pickled``).
"""

from __future__ import annotations

import pickle
import shutil
from collections import deque
from pathlib import Path

from hingelab.errors import ConfigError
from hingelab.policies.sb3_zip import read_plain_data, set_weights_from_zip
from hingelab.training import resume_state

CHECKPOINTS_DIR = "checkpoints"
MODEL_FILE = "model.zip"
BUFFER_FILE = "replay_buffer.npz"
STATE_FILE = "state.json"
PICKLED_FILES = ("state.pkl", "replay_buffer.pkl")  # an older hingelab's
# SB3's counters that a resumed model continues from (its settings come from the run's config)
MODEL_COUNTERS = ("num_timesteps", "_n_updates", "_episode_num", "_current_progress_remaining")


def checkpoint_dirs(run_dir: Path) -> list[Path]:
    """Complete checkpoints (and an older hingelab's, which ``read_state`` refuses), oldest first."""
    root = Path(run_dir) / CHECKPOINTS_DIR
    if not root.is_dir():
        return []
    return sorted(p for p in root.glob("step_*")
                  if p.is_dir() and any((p / name).exists() for name in (STATE_FILE, PICKLED_FILES[0])))


def latest_checkpoint(run_dir: Path) -> Path | None:
    found = checkpoint_dirs(run_dir)
    return found[-1] if found else None


def save_checkpoint(run_dir: Path, model, state: dict, keep: int = 2) -> Path:
    """Write ``model`` (with its replay buffer) and ``state`` as the checkpoint of ``model.num_timesteps``."""
    root = Path(run_dir) / CHECKPOINTS_DIR
    final = root / f"step_{model.num_timesteps:012d}"
    tmp = root / f".tmp_{final.name}"
    shutil.rmtree(tmp, ignore_errors=True)
    counters = {name: getattr(model, name) for name in MODEL_COUNTERS}
    episodes = {"ep_info_buffer": list(model.ep_info_buffer or []),
                "ep_success_buffer": list(model.ep_success_buffer or [])}
    try:
        tmp.mkdir(parents=True)
        model.save(tmp / MODEL_FILE)
        resume_state.save_buffer(model.replay_buffer, tmp / BUFFER_FILE)
        (tmp / STATE_FILE).write_text(resume_state.dumps(
            {**state, "rng": resume_state.rng_states(), "model": counters, "episodes": episodes}))
        if final.exists():
            shutil.rmtree(final)
        tmp.rename(final)
    except OSError as exc:
        shutil.rmtree(tmp, ignore_errors=True)
        previous = latest_checkpoint(run_dir)
        raise OSError(f"could not write checkpoint {final} ({exc}); free disk space and resume with --resume "
                      f"(the last complete checkpoint is {previous})") from exc
    for old in checkpoint_dirs(run_dir)[:-keep]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def read_state(path: Path) -> dict:
    """The ``state.json`` of checkpoint ``path``."""
    path = Path(path)
    if not (path / STATE_FILE).exists():
        if any((path / name).exists() for name in PICKLED_FILES):
            raise ConfigError(f"{path} is a checkpoint of an older hingelab, in pickles that would run code if "
                              f"read; if you trust it, `hingelab checkpoints convert {path.parent.parent}` rewrites "
                              "it in plain formats")
        raise ConfigError(f"{path} is not a complete checkpoint (no {STATE_FILE}); use another one or start anew")
    try:
        return resume_state.loads((path / STATE_FILE).read_text())
    except (OSError, ValueError) as exc:
        raise ConfigError(f"{path / STATE_FILE} is not readable ({type(exc).__name__}: {exc}); resume from an "
                          "earlier checkpoint (delete this one) or start anew") from exc


def load_checkpoint(path: Path, model) -> dict:
    """Give ``model``, built by the run from its config, the checkpoint's weights, optimizer states,
    counters and replay buffer; return the state dict. The RNG states are restored by the caller, last."""

    path = Path(path)
    state = read_state(path)
    set_weights_from_zip(model, path / MODEL_FILE)
    for name, value in state["model"].items():
        setattr(model, name, value)
    window = model._stats_window_size
    model.ep_info_buffer = deque(state["episodes"]["ep_info_buffer"], maxlen=window)
    model.ep_success_buffer = deque(state["episodes"]["ep_success_buffer"], maxlen=window)
    resume_state.load_buffer(model.replay_buffer, path / BUFFER_FILE)
    return state


def convert_pickled(run_dir: Path) -> list[Path]:
    """Rewrite the pickled checkpoints of a trusted run of an older hingelab in plain formats
    (this unpickles them: only for runs you trust). Returns the checkpoints rewritten."""

    rewritten = []
    root = Path(run_dir) / CHECKPOINTS_DIR
    for path in sorted(root.glob("step_*")) if root.is_dir() else []:
        if (path / STATE_FILE).exists() or not all((path / name).exists() for name in PICKLED_FILES):
            continue
        with open(path / "state.pkl", "rb") as f:
            state = pickle.load(f)  # noqa: S301 - the user vouches for this run (the command says so)
        with open(path / "replay_buffer.pkl", "rb") as f:
            buffer = pickle.load(f)  # noqa: S301
        plain, _ = read_plain_data(path / MODEL_FILE)
        state["rng"] = resume_state.plain_rng_states(*(state["rng"][k] for k in ("torch", "numpy", "python")))
        state["model"] = {name: plain[name] for name in MODEL_COUNTERS if name in plain}
        state["episodes"] = {"ep_info_buffer": [], "ep_success_buffer": []}  # SB3 pickled these; not read
        resume_state.save_buffer(buffer, path / BUFFER_FILE)
        (path / STATE_FILE).write_text(resume_state.dumps(state))
        for name in PICKLED_FILES:
            (path / name).unlink()
        rewritten.append(path)
    return rewritten
