"""Checkpoints load without running code: a booby-trapped encoder and a booby-trapped SAC zip (whose
unpickling would create a file) are refused or loaded without that pickle ever running."""

from __future__ import annotations

import base64
import json
import os
import pickle
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import torch

from hingelab.errors import ConfigError

ASSETS = Path(__file__).resolve().parents[1] / "assets" / "checkpoints"


class Trap:
    """Unpickling this creates ``marker`` (what a hostile checkpoint would do instead)."""

    def __init__(self, marker: Path):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.makedirs, (self.marker,))


def test_a_booby_trapped_encoder_is_refused_and_nothing_runs(tmp_path):
    from hingelab.perception.encoder import load_encoder

    marker = tmp_path / "ran"
    raw = torch.load(ASSETS / "encoder.pt", map_location="cpu", weights_only=True)
    path = tmp_path / "encoder.pt"
    torch.save({**raw, "note": Trap(marker)}, path)
    with pytest.raises(ConfigError, match="not loaded"):
        load_encoder(path)
    assert not marker.exists()


def _trap_zip(source: Path, target: Path, marker: Path) -> None:
    """``source`` with every pickled entry of its data replaced by the trap."""
    with zipfile.ZipFile(source) as archive:
        entries = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(entries["data"])
    payload = base64.b64encode(pickle.dumps(Trap(marker))).decode()
    for value in data.values():
        if isinstance(value, dict) and ":serialized:" in value:
            value[":serialized:"] = payload
    entries["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(target, "w") as archive:
        for name, content in entries.items():
            archive.writestr(name, content)


def test_a_booby_trapped_sac_zip_loads_without_its_pickles_running(tmp_path):
    from stable_baselines3 import SAC

    from hingelab.learning.high_level_checkpoint import load_high_level_checkpoint

    marker = tmp_path / "ran"
    trapped = tmp_path / "high_level.zip"
    _trap_zip(ASSETS / "high_level.zip", trapped, marker)
    model = load_high_level_checkpoint(trapped)
    assert not marker.exists()  # none of its pickled entries was unpickled
    shipped = load_high_level_checkpoint(ASSETS / "high_level.zip")
    x = np.random.default_rng(0).normal(size=(16, 17))
    assert np.array_equal(model.predict(x, deterministic=True)[0], shipped.predict(x, deterministic=True)[0])
    with pytest.raises(Exception):  # what stable-baselines3's own loader would have done (here, refused)
        SAC.load(trapped, device="cpu")
    assert marker.exists()  # ... after running the trap: the reason not to use it


def test_a_sac_zip_with_a_pickle_among_its_tensors_is_refused(tmp_path):
    from hingelab.learning.low_level_checkpoint import load_sac_checkpoint

    marker = tmp_path / "ran"
    trapped = tmp_path / "low_level.zip"
    shutil.copy(ASSETS / "low_level.zip", trapped)
    with zipfile.ZipFile(trapped, "a") as archive:
        import io

        buffer = io.BytesIO()
        torch.save({"log_ent_coef": Trap(marker)}, buffer)
        archive.writestr("pytorch_variables.pth", buffer.getvalue())  # a later duplicate name wins on read
    with pytest.raises(ConfigError, match="refused unread"):
        load_sac_checkpoint(trapped)
    assert not marker.exists()


def test_the_shipped_checkpoints_load_safely_and_as_before():
    from stable_baselines3 import SAC

    from hingelab.learning.low_level_checkpoint import load_sac_checkpoint

    for name in ("low_level.zip", "low_level_closed.zip"):
        ours, theirs = load_sac_checkpoint(ASSETS / name), SAC.load(ASSETS / name, device="cpu")
        spaces = theirs.observation_space.spaces
        observation = {k: np.random.default_rng(1).normal(size=(8, *s.shape)) for k, s in spaces.items()}
        assert np.array_equal(ours.predict(observation, deterministic=True)[0],
                              theirs.predict(observation, deterministic=True)[0])
