"""``hingelab datasets ...`` end to end, and one-line errors naming the file on bad input."""

from __future__ import annotations

import numpy as np
import pytest
from mcap.writer import Writer

from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset
from hingelab.episodes.synthetic import write_synthetic_episode


@pytest.fixture
def dataset(tmp_path):
    root = tmp_path / "ds"
    create_dataset(root, name="cli", source="synthetic", config={"x": 1}, seed=0)
    for seed in range(2):
        write_synthetic_episode(root, seed=seed, n_steps=10)
    return root


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: ")
    return err[-1]


def test_info_index_verify_on_a_good_dataset(dataset, capsys):
    assert main(["datasets", "info", str(dataset)]) == 0
    out = capsys.readouterr().out
    assert "2 episodes, 20 steps, success rate 0.500" in out and "sphere" in out
    (dataset / "index.parquet").unlink()
    assert main(["datasets", "index", str(dataset)]) == 0
    assert "from 2 episode files (20 steps)" in capsys.readouterr().out
    assert len(Dataset(dataset).index) == 2
    assert main(["datasets", "verify", str(dataset)]) == 0
    assert "all 2 episode files are complete" in capsys.readouterr().out


def test_verify_names_truncated_foreign_and_non_mcap_files(dataset, capsys):
    episodes = dataset / "episodes"
    good = sorted(episodes.glob("*.mcap"))[0]
    (episodes / "truncated.mcap").write_bytes(good.read_bytes()[:5000])
    (episodes / "notes.mcap").write_text("this is not MCAP")
    with open(episodes / "foreign.mcap", "wb") as f:  # a valid MCAP with someone else's schema
        writer = Writer(f)
        writer.start()
        schema = writer.register_schema("geometry_msgs/Pose", "ros1msg", b"float64 x")
        channel = writer.register_channel("/pose", "ros1", schema)
        writer.add_message(channel, 0, b"\x00" * 8, 0)
        writer.finish()
    assert main(["datasets", "verify", str(dataset)]) == 1
    captured = capsys.readouterr().err
    lines = captured.strip().splitlines()
    assert any("truncated.mcap: cut-off" in line and "recover" in line for line in lines)
    assert any("notes.mcap: not-mcap" in line for line in lines)
    assert any("foreign.mcap: foreign" in line and "geometry_msgs/Pose" in line for line in lines)
    assert lines[-1].startswith("hingelab: error: ") and "3 bad file(s) of 5" in lines[-1]


@pytest.mark.parametrize("name,content,expected", [
    ("truncated.mcap", None, "is cut off"),
    ("notes.mcap", b"plain text", "is not a valid MCAP file"),
])
def test_reading_bad_files_is_a_one_line_error(dataset, tmp_path, capsys, name, content, expected):
    good = sorted((dataset / "episodes").glob("*.mcap"))[0]
    bad = tmp_path / name
    bad.write_bytes(content if content is not None else good.read_bytes()[: good.stat().st_size // 2])
    (dataset / "index.parquet").unlink(missing_ok=True)
    (dataset / "episodes" / name).write_bytes(bad.read_bytes())
    assert main(["datasets", "info", str(dataset)]) == 1
    line = _one_line_error(capsys)
    assert name in line and expected in line


def test_empty_folder_and_missing_card(tmp_path, capsys):
    (tmp_path / "empty").mkdir()
    assert main(["datasets", "info", str(tmp_path / "empty")]) == 1
    line = _one_line_error(capsys)
    assert "empty" in line and "empty folder" in line
    (tmp_path / "nocard" / "episodes").mkdir(parents=True)
    assert main(["datasets", "verify", str(tmp_path / "nocard")]) == 1
    line = _one_line_error(capsys)
    assert "nocard/dataset.json is missing" in line


def test_recover_and_export_commands(dataset, tmp_path, capsys):
    good = sorted((dataset / "episodes").glob("*.mcap"))[0]
    cut = tmp_path / "cut.mcap.partial"
    cut.write_bytes(good.read_bytes()[: int(good.stat().st_size * 0.9)])
    assert main(["datasets", "recover", str(cut), "--out", str(tmp_path / "new.mcap")]) == 0
    assert "Recovered" in capsys.readouterr().out and (tmp_path / "new.mcap").exists()
    assert main(["datasets", "recover", str(cut), "--out", str(tmp_path / "new.mcap")]) == 1
    assert "choose a new --out" in _one_line_error(capsys)
    for fmt in ("minari", "lerobot"):
        assert main(["datasets", "export", str(dataset), "--format", fmt, "--out", str(tmp_path / fmt)]) == 0
        assert "Exported 2 episodes (20 steps)" in capsys.readouterr().out
    # --out: the root; the id from the dataset's folder (ds), not its card's name (cli)
    assert (tmp_path / "minari" / "hingelab" / "ds-v0" / "data" / "main_data.hdf5").exists()
    assert (tmp_path / "minari" / "hingelab" / "ds-v0" / "data" / "metadata.json").exists()
    assert [p.name for p in (tmp_path / "lerobot" / "data" / "chunk-000").glob("*.parquet")] == ["file-000.parquet"]
    for fmt in ("minari", "lerobot"):
        assert main(["datasets", "export", str(dataset), "--format", fmt, "--out", str(tmp_path / fmt)]) == 1
        assert "exists" in _one_line_error(capsys)


def test_bench_datasets_quick(tmp_path, capsys):
    assert main(["bench", "datasets", "--quick", "--out", str(tmp_path)]) == 0
    import json

    result = json.loads((tmp_path / "datasets.json").read_text())
    formats = [row["format"] for row in result["rows"]]
    assert formats[:3] == ["hingelab MCAP", "h5py, group per episode", "parquet, file per episode"]
    assert all(np.isfinite(v) and v > 0 for v in result["ratios"].values())


def test_verify_reads_length_by_schema_version():
    """Schema 2's length counts steps; version 1's also counted an env recording's reset record."""
    from hingelab.episodes.verify import _steps_match

    assert _steps_match([0, 1, 2], 3, 2) and _steps_match([1, 2, 3], 3, 2)  # with and without a reset record
    assert not _steps_match([1, 2, 3], 4, 2) and not _steps_match([0, 1, 2], 2, 2)
    assert _steps_match([1, 2, 3], 4, 1)  # a version-1 env recording: steps + the reset record
    assert not _steps_match([1, 2, 3], 5, 1)
