"""Datasets with unreadable episode files: ``--on-corrupt stop`` names them all and ends, ``skip`` leaves
them out and says so; ``datasets recover DIR`` salvages (or ``--discard``s) every leftover .partial."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hingelab.cli.main import main
from hingelab.episodes import mcap_raw
from hingelab.episodes.dataset import Dataset, corrupt_policy
from hingelab.episodes.errors import DatasetError


@pytest.fixture(scope="module")
def clean(random_pick_dataset) -> Path:
    """A dataset of 4 real ToolPick-v0 episodes (random actions, 15 steps)."""
    return random_pick_dataset("clean", episodes=4, max_episode_steps=15)


@pytest.fixture
def damaged(clean, tmp_path) -> tuple[Path, list[str]]:
    """The clean dataset with one episode's first chunk flipped and another cut in half."""
    root = tmp_path / "damaged"
    shutil.copytree(clean, root)
    files = sorted((root / "episodes").glob("*.mcap"))
    with open(files[1], "rb") as stream:
        chunk = mcap_raw.read_summary(stream).chunks[0]
    data = bytearray(files[1].read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length // 2] ^= 0xFF
    files[1].write_bytes(bytes(data))
    files[3].write_bytes(files[3].read_bytes()[: files[3].stat().st_size // 2])
    (root / "index.parquet").unlink(missing_ok=True)
    return root, [files[1].name, files[3].name]


def test_stop_names_every_bad_file_in_one_line(damaged):
    root, bad = damaged
    with pytest.raises(DatasetError) as caught:
        list(Dataset(root).iter_episodes())
    message = str(caught.value)
    assert "\n" not in message and "2 of 4" in message and all(name in message for name in bad)
    assert "--on-corrupt skip" in message and "datasets verify" in message


def test_skip_leaves_them_out_and_says_how_many(damaged, capsys):
    root, bad = damaged
    with corrupt_policy("skip"):
        dataset = Dataset(root)
        episodes = list(dataset.iter_episodes())
    assert len(episodes) == 2 and sorted(p.name for p in dataset.skipped) == sorted(bad)
    assert all(e.path.name not in bad for e in episodes)
    err = capsys.readouterr().err
    assert "left out" in err and "--on-corrupt skip" in err


def test_report_takes_on_corrupt(damaged, tmp_path, capsys):
    root, bad = damaged
    assert main(["report", str(root), "--out", str(tmp_path / "stop")]) == 1
    assert bad[0] in capsys.readouterr().err
    assert main(["report", str(root), "--out", str(tmp_path / "skip"), "--on-corrupt", "skip"]) == 0
    assert "left out" in capsys.readouterr().err


def test_recover_a_whole_folder(clean, tmp_path, capsys):
    root = tmp_path / "partials"
    shutil.copytree(clean, root)
    files = sorted((root / "episodes").glob("*.mcap"))
    for path in files[:2]:  # two writes that a crash cut off
        path.with_name(path.name + ".partial").write_bytes(path.read_bytes()[: path.stat().st_size * 2 // 3])
        path.unlink()
    assert Dataset(root).summary()["partial_files"] == 2 and len(Dataset(root)) == 2  # counted, never read
    assert main(["datasets", "recover", str(root)]) == 0
    assert "recovered 2" in capsys.readouterr().out
    assert not list((root / "episodes").glob("*.partial")) and len(Dataset(root)) == 4
    recovered = Dataset(root).index.set_index("file").loc[[p.name for p in files[:2]], "recovered"]
    assert recovered.all()
    files[2].with_name("x.mcap.partial").write_bytes(b"\x89MCAP0\r\n")
    assert main(["datasets", "recover", str(root), "--discard"]) == 0
    assert not list((root / "episodes").glob("*.partial"))
    assert main(["datasets", "recover", str(root), "--out", str(tmp_path / "x.mcap")]) == 1  # --out is for one file
