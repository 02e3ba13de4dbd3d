"""Resumable checkpoints of a SAC run: model, replay buffer, RNG states and run counters.

``RUNDIR/checkpoints/step_000010000/`` holds ``model.zip`` (SB3: weights, optimizers,
entropy coefficient, step counters), ``replay_buffer.pkl`` and ``state.pkl`` (torch and
numpy RNG states, episode counters of the envs, elapsed wall time, evaluation
bookkeeping). A checkpoint is written into a temporary folder and renamed when
complete, so a crash or a full disk never leaves a half checkpoint that looks whole;
the newest ``keep`` complete checkpoints are kept.
"""

from __future__ import annotations

import pickle
import random
import shutil
from pathlib import Path

import numpy as np
import torch

from hingelab.errors import ConfigError

CHECKPOINTS_DIR = "checkpoints"
MODEL_FILE = "model.zip"
BUFFER_FILE = "replay_buffer.pkl"
STATE_FILE = "state.pkl"


def load_sac_zip(path, observation_space, action_space):
    """A stable-baselines3 SAC zip for these spaces, loaded on the CPU without unpickling anything of it
    (``safe_sb3``); a file that is not one, or does not fit them, is a one-line ConfigError."""
    from hingelab.learning.safe_sb3 import load_sac_zip_safely

    if not Path(path).is_file():
        raise ConfigError(f"{path} does not exist; give a SAC checkpoint (.zip)")
    return load_sac_zip_safely(path, observation_space, action_space, device="cpu")


def rng_states() -> dict:
    return {"torch": torch.get_rng_state(), "numpy": np.random.get_state(), "python": random.getstate()}


def restore_rng_states(states: dict) -> None:
    torch.set_rng_state(states["torch"])
    np.random.set_state(states["numpy"])
    random.setstate(states["python"])


def checkpoint_dirs(run_dir: Path) -> list[Path]:
    """Complete checkpoints, oldest first."""
    root = Path(run_dir) / CHECKPOINTS_DIR
    if not root.is_dir():
        return []
    return sorted(p for p in root.glob("step_*") if p.is_dir() and (p / STATE_FILE).exists())


def latest_checkpoint(run_dir: Path) -> Path | None:
    found = checkpoint_dirs(run_dir)
    return found[-1] if found else None


def save_checkpoint(run_dir: Path, model, state: dict, keep: int = 2) -> Path:
    """Write ``model`` (with its replay buffer) and ``state`` as the checkpoint of ``model.num_timesteps``."""
    root = Path(run_dir) / CHECKPOINTS_DIR
    final = root / f"step_{model.num_timesteps:012d}"
    tmp = root / f".tmp_{final.name}"
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        tmp.mkdir(parents=True)
        model.save(tmp / MODEL_FILE)
        model.save_replay_buffer(tmp / BUFFER_FILE)
        with open(tmp / STATE_FILE, "wb") as f:
            pickle.dump({**state, "rng": rng_states(), "num_timesteps": model.num_timesteps}, f)
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


def load_checkpoint(path: Path, algorithm_class, env, device: str = "cpu"):
    """(model with its replay buffer, state dict). The RNG states are restored by the caller, last."""
    path = Path(path)
    if not (path / STATE_FILE).exists():
        raise ConfigError(f"{path} is not a complete checkpoint (no {STATE_FILE}); use another one or start anew")
    model = algorithm_class.load(path / MODEL_FILE, env=env, device=device)
    model.load_replay_buffer(path / BUFFER_FILE)
    with open(path / STATE_FILE, "rb") as f:
        state = pickle.load(f)
    return model, state
