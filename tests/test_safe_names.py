"""Names never come from data: a metadata value (an episode id, a dataset's name, a path in an export's
info) becomes a file name only through ``hingelab.safe_names``, and a value that is not a plain file name
is refused in one line, nothing written outside ``--out``; ``datasets verify`` reports it."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.episodes.writer import EpisodeWriter
from hingelab.errors import HingelabError
from hingelab.safe_names import MAX_NAME_CHARS, UnsafeNameError, safe_file_name, safe_relative_path

# values a crafted file may hold where a name belongs ("ABS" becomes an absolute path inside the test's folder)
UNSAFE = {
    "parent": "../../escaped",
    "deep-parent": "../../../../../../escaped",
    "absolute": "ABS",
    "separator": "a/b",
    "backslash": "a\\..\\b",
    "dot": ".",
    "dotdot": "..",
    "newline": "ep\nhingelab: error: forged",
    "nul": "ep\x00x",
    "escape": "\x1b[31mred",
    "delete": "ep\x7f",
    "long": "x" * (MAX_NAME_CHARS + 1),
    "very-long": "y" * 100_000,
    "empty": "",
}


def _value(key: str, tmp_path: Path) -> str:
    return str(tmp_path / "abs_target") if UNSAFE[key] == "ABS" else UNSAFE[key]


def _files(root: Path) -> set[str]:
    """Every path under ``root`` but a dataset's index cache (reading a dataset may rebuild it)."""
    return {str(p.relative_to(root)) for p in root.rglob("*") if p.name != "index.parquet"}


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: ") and "Traceback" not in "\n".join(err)
    return err[-1]


def _work(tmp_path: Path) -> Path:
    """A folder deep enough that ``../..`` from inside it stays inside ``tmp_path`` (where the test looks)."""
    work = tmp_path / "a" / "b" / "c"
    work.mkdir(parents=True)
    return work


def _dataset(root: Path, episode_id: str | None = None, name: str = "crafted") -> Path:
    create_dataset(root, name="crafted", source="synthetic", seed=0, config={})
    extra = {} if episode_id is None else {"episode_id": episode_id}
    write_synthetic_episode(root, 0, n_steps=3, extra_metadata=extra)
    if name != "crafted":  # a card that says anything
        card = json.loads((root / "dataset.json").read_text())
        card["name"] = name
        (root / "dataset.json").write_text(json.dumps(card))
    return root


@pytest.mark.parametrize("value", ["episode-1", "real-20240101T000000-abcdef012345", "ünïcode name", "a.b_c-d",
                                   "x" * MAX_NAME_CHARS, "..hidden", "mesh:box.stl"])
def test_plain_file_names_pass(value):
    assert safe_file_name(value, "episode_id", "f.mcap") == value


@pytest.mark.parametrize("key", sorted(UNSAFE))
def test_every_unsafe_value_is_one_line_naming_the_file_and_the_field(key, tmp_path):
    with pytest.raises(UnsafeNameError) as caught:
        safe_file_name(_value(key, tmp_path), "episode_id", "/data/d/episodes/e.mcap")
    message = str(caught.value)
    assert "\n" not in message and "\x00" not in message and "\x1b" not in message and len(message) < 600
    assert message.startswith("/data/d/episodes/e.mcap: episode_id ") and isinstance(caught.value, HingelabError)


def test_relative_paths_from_data_stay_inside():
    assert safe_relative_path("data/chunk-000/file-000.parquet", "data_path", "info.json") == Path(
        "data/chunk-000/file-000.parquet")
    for bad in ("../x.parquet", "/etc/passwd", "data/../../x", "data//x", "a\nb/x"):
        with pytest.raises(UnsafeNameError):
            safe_relative_path(bad, "data_path", "info.json")


@pytest.mark.parametrize("key", sorted(UNSAFE))
def test_ros2_export_refuses_an_unsafe_episode_id_and_writes_nothing(key, tmp_path, capsys):
    """The finding: an episode whose id is ../../x made the export write there, exit 0 and leave --out empty."""
    work = _work(tmp_path)
    value = _value(key, tmp_path)
    root = _dataset(work / "d", episode_id=value)
    before = _files(tmp_path)
    out = work / "out"
    assert main(["datasets", "export", str(root), "--format", "ros2", "--out", str(out)]) == 1
    line = _one_line_error(capsys)
    assert "episode_id" in line and root.name in line
    assert _files(tmp_path) == before  # nothing anywhere: not outside --out, not --out itself


@pytest.mark.parametrize("key", ["parent", "absolute", "newline", "long", "dotdot"])
def test_verify_reports_an_unsafe_episode_id(key, tmp_path, capsys):
    root = _dataset(tmp_path / "d", episode_id=_value(key, tmp_path))
    assert main(["datasets", "verify", str(root)]) == 1
    err = capsys.readouterr().err
    assert "unsafe-name: episode_id" in err and "all 1 episode files are complete" not in err


@pytest.mark.parametrize("key", ["parent", "absolute", "newline", "very-long"])
def test_verify_reports_an_unsafe_dataset_name(key, tmp_path, capsys):
    root = _dataset(tmp_path / "d", name=_value(key, tmp_path))
    assert main(["datasets", "verify", str(root)]) == 1
    assert "dataset.json: unsafe-name: the dataset's name" in capsys.readouterr().err


@pytest.mark.parametrize("key", sorted(UNSAFE))
def test_minari_export_of_a_crafted_dataset_name_stays_inside_out(key, tmp_path, capsys):
    """The default Minari id is made from the card's name: whatever it says, the export lands inside --out."""
    work = _work(tmp_path)
    root = _dataset(work / "d", name=_value(key, tmp_path))
    before = _files(tmp_path)
    out = work / "minari"
    assert main(["datasets", "export", str(root), "--format", "minari", "--out", str(out)]) == 0
    capsys.readouterr()
    new = _files(tmp_path) - before
    assert new and all(name.startswith(str(out.relative_to(tmp_path))) for name in new)


def test_a_minari_dataset_id_is_one_line_when_unsafe(tmp_path, capsys):
    root = _dataset(tmp_path / "d")
    assert main(["datasets", "export", str(root), "--format", "minari", "--out", str(tmp_path / "m"),
                 "--dataset-id", "a//b/x-v0"]) == 1
    assert "--dataset-id" in _one_line_error(capsys) and not (tmp_path / "m").exists()


@pytest.mark.parametrize("key", ["parent", "absolute", "newline", "very-long", "dotdot"])
def test_view_does_not_name_its_recording_by_an_unsafe_dataset_name(key, tmp_path, monkeypatch, capsys):
    """Without a display, ``hingelab view DIR`` saves ./<dataset name>.rrd: the name comes from the card."""
    work = _work(tmp_path)
    root = _dataset(work / "d", name=_value(key, tmp_path))
    monkeypatch.chdir(work)
    for name in ("DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    before = _files(tmp_path)
    assert main(["view", str(root)]) == 1
    line = _one_line_error(capsys)
    assert "the dataset card's name" in line and "--save" in line
    assert _files(tmp_path) == before


@pytest.mark.parametrize("key", ["parent", "absolute", "separator", "dotdot", "long", "newline"])
def test_the_writer_refuses_an_unsafe_episode_id(key, tmp_path):
    root = tmp_path / "a" / "b" / "d"
    create_dataset(root, name="d", source="synthetic", seed=0, config={})
    before = _files(tmp_path)
    with pytest.raises(UnsafeNameError):
        EpisodeWriter(root, source="synthetic", episode_id=_value(key, tmp_path))
    assert _files(tmp_path) == before


def test_a_source_from_data_gives_a_bounded_episode_file_name(tmp_path):
    root = tmp_path / "d"
    create_dataset(root, name="d", source="imported", seed=0, config={})
    writer = EpisodeWriter(root, source="../" * 500 + "\n")
    assert writer.path.parent == root / "episodes" and len(writer.path.name) <= MAX_NAME_CHARS + len(".mcap")


def test_lerobot_import_refuses_a_data_path_outside_the_export(tmp_path):
    from hingelab.episodes.dataset import Dataset
    from hingelab.episodes.export import export_lerobot, import_lerobot

    root = _dataset(tmp_path / "d")
    export_lerobot(Dataset(root), tmp_path / "lr")
    info_path = tmp_path / "lr" / "meta" / "info.json"
    info = json.loads(info_path.read_text())
    for bad in ("../../outside/file-{file_index:03d}.parquet", os.sep + "etc/{chunk_index}.parquet",
                "data/{nope}.parquet"):
        info["data_path"] = bad
        info_path.write_text(json.dumps(info))
        with pytest.raises(HingelabError) as caught:
            import_lerobot(tmp_path / "lr", tmp_path / f"back{len(bad)}")
        assert "data_path" in str(caught.value) and "\n" not in str(caught.value)
