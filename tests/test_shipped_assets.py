"""Shipped files under assets/ are replaced only on purpose (--force), never by a default output path."""

from __future__ import annotations

import hashlib

import pytest

from hingelab import paths
from hingelab.cli.main import main


def _digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def checkout(tmp_path, monkeypatch):
    """A stand-in repository: its assets/ with a shipped encoder, and a cloud dataset to train on."""
    root = tmp_path / "repo"
    shipped = root / "assets" / "checkpoints" / "encoder.pt"
    shipped.parent.mkdir(parents=True)
    shipped.write_bytes(b"the shipped encoder")
    data = tmp_path / "clouds"
    assert main(["generate", "clouds", "--n", "120", "--per-episode", "60", "--out", str(data), "--seed", "1",
                 "--no-progress"]) == 0
    monkeypatch.setattr(paths, "REPO_ROOT", root)  # its assets/ counts as shipped beside the real ASSETS_DIR
    return root, shipped, data


def _last_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: "), err
    return err[-1]


def test_train_encoder_writes_a_run_folder_and_never_replaces_assets_without_force(checkout, capsys):
    root, shipped, data = checkout
    before = _digest(shipped)
    toy = ["--epochs", "1", "--batch-size", "32", "--no-progress"]
    assert main(["train", "encoder", "--data", str(data), *toy, "--seed", "5"]) == 0
    assert (root / "runs" / "encoder_seed5" / "encoder.pt").is_file()
    assert _digest(shipped) == before
    # the same default path again: the run's own checkpoint is not replaced silently either
    assert main(["train", "encoder", "--data", str(data), *toy, "--seed", "5"]) == 1
    assert "exists" in _last_error(capsys)
    for extra in ([], ["--recalibrate"]):
        assert main(["train", "encoder", "--data", str(data), *toy, *extra, "--out", str(shipped)]) == 1
        line = _last_error(capsys)
        assert "would replace a shipped file under assets/" in line and "--force" in line
    assert main(["train", "encoder", "--recalibrate-curve", "--out", str(shipped)]) == 1
    assert "--force" in _last_error(capsys)
    assert _digest(shipped) == before
    assert main(["train", "encoder", "--data", str(data), *toy, "--out", str(shipped), "--force"]) == 0
    assert _digest(shipped) != before  # on purpose, it does


def test_recalibration_needs_a_named_checkpoint(checkout, capsys):
    _, _, data = checkout
    assert main(["train", "encoder", "--data", str(data), "--recalibrate"]) == 1
    assert "name it with --out" in _last_error(capsys)


def test_compose_and_train_low_refuse_assets(checkout, capsys):
    root, shipped, _ = checkout
    manifest = root / "assets" / "checkpoints" / "low_level_experts.json"
    manifest.write_text("{}")
    assert main(["compose", "low", "--expert", "a.zip:0.1", "--expert", "b.zip", "--out", str(manifest)]) == 1
    assert "--force" in _last_error(capsys) and manifest.read_text() == "{}"
    assert main(["train", "low", "--steps", "10", "--out", str(root / "assets" / "checkpoints")]) == 1
    assert "--force" in _last_error(capsys)
