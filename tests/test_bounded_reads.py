"""Bounded reads: a dangling symlink or a symlink loop is reported as an unreadable file (never a
traceback)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hingelab.bounded_reads import resolved_input, unreadable_reason
from hingelab.cli.main import main
from hingelab.episodes import create_dataset
from hingelab.episodes.dataset import Dataset, corrupt_policy
from hingelab.episodes.synthetic import write_synthetic_episode
from hingelab.errors import ConfigError


def _one_line_error(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("hingelab: error: ") and "Traceback" not in "\n".join(err)
    return err[-1]


# ------------------------------------------------------------------------------------------- symlinks
@pytest.fixture
def linked(tmp_path) -> Path:
    """A dataset of two sound episodes, a dangling .mcap symlink and a .mcap symlink loop."""
    root = tmp_path / "linked"
    create_dataset(root, name="linked", source="synthetic", seed=0, config={})
    for seed in range(2):
        write_synthetic_episode(root, seed, n_steps=4)
    (root / "episodes" / "gone.mcap").symlink_to(tmp_path / "moved_away.mcap")
    (root / "episodes" / "loop.mcap").symlink_to(root / "episodes" / "loop.mcap")
    return root


def test_unreadable_reason_names_dangling_links_and_loops(linked):
    assert "dangling symlink" in unreadable_reason(linked / "episodes" / "gone.mcap")
    assert "symlink loop" in unreadable_reason(linked / "episodes" / "loop.mcap")
    assert unreadable_reason(linked / "dataset.json") is None
    assert unreadable_reason(linked, "folder") is None and "folder" in unreadable_reason(linked)


@pytest.mark.parametrize("verb", ["info", "index"])
def test_datasets_info_and_index_report_dangling_links_and_loops(linked, verb, capsys):
    assert main(["datasets", verb, str(linked)]) == 1
    line = _one_line_error(capsys)
    assert "2 of 4 episode files cannot be read (gone.mcap, loop.mcap)" in line and "dangling symlink" in line
    assert main(["datasets", verb, str(linked), "--on-corrupt", "skip"]) == 0
    assert "left out 2 of 4" in capsys.readouterr().err


def test_report_reports_dangling_links_and_loops(linked, tmp_path, capsys):
    assert main(["report", str(linked), "--out", str(tmp_path / "report")]) == 1
    assert "gone.mcap" in _one_line_error(capsys)


def test_verify_reports_them_as_unreadable(linked, capsys):
    assert main(["datasets", "verify", str(linked)]) == 1
    err = capsys.readouterr().err
    assert "gone.mcap: unreadable: is a dangling symlink" in err and "loop.mcap: unreadable: is a symlink loop" in err
    assert "2 bad file(s) of 4" in err


def test_iteration_under_skip_leaves_them_out(linked):
    with corrupt_policy("skip"):
        dataset = Dataset(linked)
        assert len(list(dataset.iter_episodes())) == 2


def test_train_high_from_a_symlink_loop_is_one_line(tmp_path, capsys):
    loop = tmp_path / "demos"
    loop.symlink_to(loop)
    out = tmp_path / "run"
    assert main(["train", "high", "--from", str(loop), "--steps", "60", "--out", str(out), "--no-progress"]) == 1
    line = _one_line_error(capsys)
    assert "--from" in line and "symlink loop" in line and not out.exists()
    with pytest.raises(ConfigError, match="--init-from .* symlink loop"):
        resolved_input(loop, "--init-from")
