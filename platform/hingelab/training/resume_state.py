"""A SAC run's resume state in plain formats: the replay buffer as ``.npz``, the rest as JSON.

Nothing here unpickles: ``np.load(allow_pickle=False)`` reads the buffer, ``json`` the state.

* **Replay buffer** (``save_buffer`` / ``load_buffer``): every array of the buffer object (SB3's
  ``ReplayBuffer``, ``DictReplayBuffer``, ``HerReplayBuffer``, the platform's
  ``DemoShareReplayBuffer``) and of any buffer it holds (the demo store, under ``demos.``),
  dict observations per key, and its plain counters (``pos``, ``full``, ...). Of the ring arrays
  only the rows written so far are stored. HER's per-slot info
  dicts (an object array, for the effort term of the reward) go as JSON of the filled slots. On
  load the run has built its own buffer from its config; the saved arrays are copied into it
  in place and must have its shapes and dtypes, else a one-line ``ConfigError``.
* **State** (``state_to_json`` / ``state_from_json``): RNG states of torch, numpy and Python, the
  counters and schedules of the run, the rollouts' episode statistics. NumPy scalars and
  arrays are tagged with their dtype and come back as they were.
"""

from __future__ import annotations

import json
import math
import random
import zipfile
from collections import deque
from pathlib import Path

import numpy as np
import torch
from stable_baselines3.common.buffers import BaseBuffer

from hingelab.errors import ConfigError

COUNTERS = ("pos", "full")  # the buffer's scalars that change as it fills; the others are settings
META_KEY = "__meta__"  # the buffer's counters and object arrays, as JSON bytes inside the npz


def _finite(value):
    """``value`` with each NaN or infinity (at any depth) as ``{"__float__": "nan" | "inf" | "-inf"}``: the state
    is exact JSON (``allow_nan=False``) and still comes back bit for bit (a NaN reward statistic included)."""
    if isinstance(value, float) and not math.isfinite(value):
        return {"__float__": repr(value)}
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite(v) for v in value]
    return value


def _plain(value):
    """``json.dumps`` default: NumPy scalars and arrays tagged with their dtype, deques as lists."""
    if isinstance(value, np.generic):  # the dtype kept: a float32 reward term stays float32
        return {"__scalar__": _finite(value.item()), "dtype": str(value.dtype)}
    if isinstance(value, np.ndarray):
        return {"__ndarray__": _finite(value.tolist()), "dtype": str(value.dtype)}
    if isinstance(value, deque):
        return _finite(list(value))
    raise TypeError(f"{type(value).__name__} is not stored in a plain checkpoint")


def _unplain(doc: dict):
    if set(doc) == {"__float__"}:
        return float(doc["__float__"])
    if set(doc) == {"__ndarray__", "dtype"}:
        return np.asarray(doc["__ndarray__"], dtype=doc["dtype"])
    if set(doc) == {"__scalar__", "dtype"}:
        return np.dtype(doc["dtype"]).type(doc["__scalar__"])
    return doc


def dumps(doc) -> str:
    return json.dumps(_finite(doc), default=_plain, allow_nan=False)


def loads(text: str):
    return json.loads(text, object_hook=_unplain)


# ---------------------------------------------------------------------- RNG states
def rng_states() -> dict:
    return plain_rng_states(torch.get_rng_state(), np.random.get_state(), random.getstate())


def plain_rng_states(torch_state, numpy_state, python_state) -> dict:
    """The three generators' states (as their ``get_state`` functions give them) as JSON values."""
    name, keys, pos, has_gauss, cached = numpy_state
    version, internal, gauss_next = python_state
    return {"torch": torch_state.tolist(),
            "numpy": [name, keys.tolist(), int(pos), int(has_gauss), float(cached)],
            "python": [version, list(internal), gauss_next]}


def restore_rng_states(states: dict) -> None:
    torch.set_rng_state(torch.tensor(states["torch"], dtype=torch.uint8))
    name, keys, pos, has_gauss, cached = states["numpy"]
    np.random.set_state((name, np.asarray(keys, dtype=np.uint32), pos, has_gauss, cached))
    version, internal, gauss_next = states["python"]
    random.setstate((version, tuple(internal), gauss_next))


# ---------------------------------------------------------------------- replay buffers
def _is_buffer(value) -> bool:

    return isinstance(value, BaseBuffer)


def _collect(buffer, prefix: str, arrays: dict, meta: dict) -> None:
    size = buffer.buffer_size
    filled = size if buffer.full else buffer.pos

    def ring_rows(key: str, array: np.ndarray) -> np.ndarray:
        """Only the rows written so far of a ring array (a fresh 1M buffer is gigabytes of zeros)."""
        if array.ndim and array.shape[0] == size and not key.rpartition(".")[2].startswith("_"):
            meta["rows"][key] = [int(filled), *array.shape[1:]]
            return array[:filled]
        return array

    for name, value in vars(buffer).items():
        key = prefix + name
        if isinstance(value, np.ndarray) and value.dtype == object:  # HER's info dicts
            cells = [[int(i), int(j), cell] for (i, j), cell in np.ndenumerate(value) if cell]
            meta["objects"][key] = {"shape": list(value.shape), "filled": cells}
        elif isinstance(value, np.ndarray):
            arrays[key] = ring_rows(key, value)
        elif isinstance(value, dict) and value and all(isinstance(v, np.ndarray) for v in value.values()):
            for part, array in value.items():
                arrays[f"{key}/{part}"] = ring_rows(f"{key}/{part}", array)
        elif isinstance(value, (bool, int, float, np.generic)):
            meta["scalars"][key] = value
        elif _is_buffer(value):  # the demo store of a DemoShareReplayBuffer
            _collect(value, key + ".", arrays, meta)


def save_buffer(buffer, path: Path) -> None:
    """Write ``buffer`` (and the buffers it holds) to ``path`` (.npz, uncompressed)."""
    arrays: dict[str, np.ndarray] = {}
    meta: dict = {"class": type(buffer).__name__, "scalars": {}, "objects": {}, "rows": {}}
    _collect(buffer, "", arrays, meta)
    with open(path, "wb") as f:
        np.savez(f, **arrays, **{META_KEY: np.frombuffer(dumps(meta).encode(), dtype=np.uint8)})


def _owner(buffer, key: str, path: Path):
    """(object, attribute) of a dotted key; a nested buffer the run's own buffer lacks is refused."""
    *parents, name = key.split(".")
    owner = buffer
    for parent in parents:
        owner = getattr(owner, parent, None)
        if owner is None:
            raise ConfigError(f"{path}: the checkpoint's replay buffer has {'.'.join(parents)}, this run's buffer "
                              "has none (its config differs from the run's config.json?)")
    return owner, name


def _fits(path: Path, key: str, ours, saved: np.ndarray, rows: bool) -> None:
    """``ours`` has ``saved``'s dtype and shape (``rows``: its shape but for the number of rows, at least
    ``saved``'s: the written rows of a ring array)."""
    fits = isinstance(ours, np.ndarray) and ours.dtype == saved.dtype and (
        ours.shape[1:] == saved.shape[1:] and ours.shape[0] >= saved.shape[0] if rows else ours.shape == saved.shape)
    if not fits:
        found = "nothing" if not isinstance(ours, np.ndarray) else f"{ours.dtype}{list(ours.shape)}"
        raise ConfigError(f"{path}: the checkpoint's replay buffer {key} is {saved.dtype}{list(saved.shape)}"
                          f"{' (rows written)' if rows else ''}, this run's is {found}; resume with the config the "
                          "run was started with")


def load_buffer(buffer, path: Path) -> None:
    """Copy the buffer saved at ``path`` into ``buffer``, built by the run with the same config."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as saved:
            meta = loads(saved[META_KEY].tobytes().decode())
            if meta["class"] != type(buffer).__name__:
                raise ConfigError(f"{path} holds a {meta['class']}, this run uses a {type(buffer).__name__}; resume "
                                  "with the config the run was started with")
            for key, value in meta["scalars"].items():
                owner, name = _owner(buffer, key, path)
                if name in COUNTERS:
                    setattr(owner, name, value)
                elif getattr(owner, name, None) != value:  # a setting (buffer_size, demo_share, her_ratio, ...)
                    raise ConfigError(f"{path}: the checkpoint's replay buffer has {key}={value!r}, this run's "
                                      f"{getattr(owner, name, None)!r}; resume with the config the run was started "
                                      "with")
            for key in saved.files:
                if key == META_KEY:
                    continue
                attribute, _, part = key.partition("/")
                owner, name = _owner(buffer, attribute, path)
                ours = getattr(owner, name, None)
                if part:
                    ours = ours.get(part) if isinstance(ours, dict) else None
                array, rows = saved[key], key in meta["rows"]
                _fits(path, key, ours, array, rows)
                # in place (samplers that hold views of the arrays stay valid); unwritten rows stay as built
                if rows:
                    ours[:len(array)] = array
                else:
                    ours[...] = array
    except ConfigError:
        raise
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path} is not a readable replay buffer ({type(exc).__name__}: {exc}); resume from "
                          "an earlier checkpoint (delete this one) or start anew") from exc
    for key, doc in meta["objects"].items():
        owner, name = _owner(buffer, key, path)
        rows, columns = doc["shape"]
        cells = np.array([[{} for _ in range(columns)] for _ in range(rows)])
        for i, j, cell in doc["filled"]:
            cells[i, j] = cell
        setattr(owner, name, cells)


__all__ = ["save_buffer", "load_buffer", "rng_states", "plain_rng_states", "restore_rng_states", "dumps", "loads"]
